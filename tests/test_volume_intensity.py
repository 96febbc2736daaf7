"""Intensities become materials: the curve's blend (eq. 1 with the image value for r), its halftone (every solid
pixel in exactly one mask; each material's share following its fraction within 2 % over any 2 mm x 2 mm window
of constant value), and a CT sliced through the materials file's [intensity] table."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import CT_CURVE, CT_MATERIALS, in_process
from volume_phantoms import grid_affine, write_nifti

from heoslice.errors import InputError
from heoslice.material import read_materials_file
from heoslice.stack import read_layer_channels, read_layer_mask
from heoslice.grading.halftone import METHODS, halftone
from heoslice.volume.intensity import read_curve

MATERIALS = CT_MATERIALS + CT_CURVE


def curve(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(MATERIALS)
    table = read_materials_file(path)
    return read_curve(table.data["intensity"], table.materials)



def middle_layer(stack):
    """(manifest, solid (H, W) bool, masks (K, H, W) bool) of the stack's middle layer, after checking that every
    solid pixel is in exactly one droplet mask there."""
    manifest = json.loads((stack / "manifest.json").read_text())
    middle = len(manifest["layers"]) // 2
    solid = read_layer_mask(stack, manifest, middle).astype(bool)
    masks = read_layer_channels(stack, manifest, middle).astype(bool)
    assert np.array_equal(masks.sum(axis=0), solid.astype(int))
    return manifest, solid, masks

def test_curve_blends_linearly_and_holds_its_ends(tmp_path):
    """Bone fraction (value - 100) / 800 between the points, 0 below, 1 above; fractions sum to 1."""
    blend = curve(tmp_path)
    values = np.array([-500.0, 100.0, 300.0, 500.0, 900.0, 2000.0])
    mix = blend.mix(values)
    names = [material.name for material in blend.materials]
    bone = mix[:, names.index("bone")]
    assert np.allclose(bone, np.clip((values - 100) / 800, 0, 1)) and np.allclose(mix.sum(axis=1), 1)


@pytest.mark.parametrize("method", list(METHODS))
@pytest.mark.parametrize("fraction", [0.1, 0.25, 0.5, 0.8])
def test_halftone_share_follows_the_fraction(fraction, method):
    """The halftone a CT's curve goes through (grading.halftone.halftone, every method): over every 2 mm x 2 mm
    window (47 x 47 px at 600 dpi) of constant mix, each material's share is its fraction within 2 %; every
    solid pixel is in one mask."""
    shape = (200, 300)
    mix = np.zeros((*shape, 2), np.float32)
    mix[..., 0], mix[..., 1] = 1 - fraction, fraction
    solid = np.ones(shape, bool)
    solid[:, :20] = False
    masks = halftone(mix * solid[..., None], 7, method)
    assert np.array_equal(masks.sum(axis=0), solid.astype(int))
    for top in range(0, 200 - 47, 31):
        for left in range(20, 300 - 47, 37):
            share = masks[1, top:top + 47, left:left + 47].mean()
            assert abs(share - fraction) <= 0.02


def test_unknown_material_in_the_curve_is_one_line(tmp_path):
    table = read_materials_file(None)
    with pytest.raises(InputError, match="unknown material 'bone'"):
        read_curve({"points": [{"value": 1, "mix": {"bone": 1.0}}]}, table.materials)


def test_ct_sliced_by_its_curve(tmp_path, capsys):
    """A CT of two slabs (300 and 700 HU) in air (-1000 HU): air is not printed; inside the slabs (away from
    their boundary) the bone mask's share is 0.25 and 0.75 within 2 % over 2 mm windows."""
    hu = np.full((20, 16, 10), -1000, np.int16)
    hu[2:10, 2:14, 2:8] = 300
    hu[10:18, 2:14, 2:8] = 700
    path = write_nifti(tmp_path / "ct.nii.gz", hu, grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "m.toml").write_text(MATERIALS)
    assert in_process("slice", path, "--materials", tmp_path / "m.toml", "--layer", "0.5", "--dpi", "600", "-o",
                      tmp_path / "out", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["materials"] == ["tissue", "bone"]
    manifest, solid, masks = middle_layer(tmp_path / "out")
    left, top = manifest["image"]["origin_mm"]
    px = manifest["pixel_size_mm"][0]
    for x_mm, share in ((8.0, 0.25), (28.0, 0.75)):  # slab centres: x 4..20 mm at 300 HU, 20..36 mm at 700 HU
        column, row = int((x_mm - 1.0 - left) / px), int((top - 15.0) / px)
        window = masks[1, row:row + 47, column:column + 47]
        assert solid[row:row + 47, column:column + 47].all() and abs(window.mean() - share) <= 0.02
    air = int((top - 28.0) / px)  # y = 28 mm: past the slabs (300 HU at y 26, air at 28: 100 HU at y 26.3)
    assert not solid[air].any()


def test_ct_bone_by_its_curve_and_labelled_soft_tissue_in_one_job(tmp_path, capsys):
    """CT + label map in one job: label 1 ('bone', 700 HU) prints by the curve (bone share 0.75 within 2 % over
    a 2 mm window), label 2 prints as tissue whatever its HU, every solid pixel in exactly one mask, and the
    CT's 700 HU outside the labels (label 0) does not print."""
    hu = np.full((24, 16, 10), -1000, np.int16)
    hu[2:10, 2:14, 2:8] = 700
    hu[10:18, 2:14, 2:8] = 0
    hu[18:22, 2:14, 2:8] = 700  # dense, but in no label
    labels = np.zeros(hu.shape, np.uint8)
    labels[2:10, 2:14, 2:8] = 1
    labels[10:18, 2:14, 2:8] = 2
    ct = write_nifti(tmp_path / "ct.nii.gz", hu, grid_affine(2.0, [0, 0, 0]))
    seg = write_nifti(tmp_path / "seg.nii.gz", labels, grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "m.toml").write_text(MATERIALS + 'within = [1]\n[labels]\n2 = "tissue"\n')
    assert in_process("slice", ct, "--labels", seg, "--materials", tmp_path / "m.toml", "--layer", "0.5", "--dpi",
                      "600", "-o", tmp_path / "out", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["materials"] == ["tissue", "bone"]
    manifest, solid, masks = middle_layer(tmp_path / "out")
    left, top = manifest["image"]["origin_mm"]
    px = manifest["pixel_size_mm"][0]
    row = int((top - 16.0) / px)
    bone = int((10.0 - left) / px)  # x 10 mm: inside label 1 (x 4..18 mm)
    window = masks[1, row:row + 47, bone:bone + 47]
    assert solid[row:row + 47, bone:bone + 47].all() and abs(window.mean() - 0.75) <= 0.02
    tissue = int((28.0 - left) / px)  # x 28 mm: inside label 2 (x 20..34 mm)
    assert masks[0, row:row + 47, tissue:tissue + 47].all()
    beyond = int(np.ceil((36.2 - left) / px))  # past label 2 (face 35, its rounded box bulges < 1 mm): the dense slab
    assert beyond < solid.shape[1] and not solid[:, beyond:].any()


def test_a_within_label_below_the_curves_first_point_is_air(tmp_path):
    """Inside a label the [intensity] table's 'within' prints by the CT, the voxels below the curve's first point
    are not printed (air), as a CT sliced alone leaves them: a -1000 HU hollow inside label 1 stays empty, its
    700 HU rest prints."""
    hu = np.full((24, 16, 10), -1000, np.int16)
    hu[2:20, 2:14, 2:8] = 700
    hu[8:14, 6:10, 2:8] = -1000  # a hollow (marrow, a pore) inside the label
    labels = np.zeros(hu.shape, np.uint8)
    labels[2:20, 2:14, 2:8] = 1
    ct = write_nifti(tmp_path / "ct.nii.gz", hu, grid_affine(2.0, [0, 0, 0]))
    seg = write_nifti(tmp_path / "seg.nii.gz", labels, grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "m.toml").write_text(MATERIALS + 'within = [1]\n')
    assert in_process("slice", ct, "--labels", seg, "--materials", tmp_path / "m.toml", "--layer", "0.5", "--dpi",
                      "200", "-o", tmp_path / "out") == 0
    manifest, solid, _ = middle_layer(tmp_path / "out")
    left, top = manifest["image"]["origin_mm"]
    px = manifest["pixel_size_mm"][0]
    row, hollow, dense = int((top - 16.0) / px), int((22.0 - left) / px), int((8.0 - left) / px)
    assert not solid[row, hollow] and solid[row, dense]


def test_a_scans_end_slices_print_their_whole_thickness(tmp_path):
    """A CT's voxels are cells, as a label map's are: a slab filling the scan's 5 slices of 2 mm prints 10 mm of
    layers (half a slice beyond the first and last slice centres), not the 8 mm between those centres."""
    hu = np.full((12, 12, 5), -1000, np.int16)
    hu[2:10, 2:10, :] = 700
    ct = write_nifti(tmp_path / "ct.nii.gz", hu, grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "m.toml").write_text(MATERIALS)
    assert in_process("slice", ct, "--materials", tmp_path / "m.toml", "--layer", "0.5", "--dpi", "100", "-o",
                      tmp_path / "out") == 0
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    printed = [entry["z_mm"] for entry in manifest["layers"] if entry["solid_pixels"]]
    assert len(printed) * 0.5 == pytest.approx(10.0, abs=0.5)
    assert min(printed) < 0.0 < 8.0 < max(printed)  # below the first slice's centre (z 0), above the last (z 8)
