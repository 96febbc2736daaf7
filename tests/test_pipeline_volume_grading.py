"""Grading inside a label by distance (pipeline.volume_grading): a sphere label (the "liver", radius 20 mm, 1 mm
voxels) with an inner sphere label (the "tumour", radius 6 mm, off centre) graded toward the tumour, and the
sphere graded from its own boundary: the delivered share of the target material in each 2 mm band of the
analytic distance is within 2 % of the design's f(r) averaged over the band's pixels; every solid pixel is in
exactly one droplet mask; a key naming two labels grades each from its own surface; --halftone halftones the
graded labels and the manifest records it; [grade] mistakes are one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from helpers import in_process
from volume_phantoms import FLIP_XY, grid_affine, voxel_centres, write_nifti, write_nrrd

from heoslice.errors import InputError
from heoslice.material import read_materials_file
from heoslice.pipeline import SliceSpec
from heoslice.pipeline.volume_grading import read_grades, resolve_grades
from heoslice.pipeline.volume_job import plan_labels, slice_volume_to_stack
from heoslice.stack import encode_bilevel_tiff, read_layer_channels, read_layer_mask
from heoslice.stack.tiff import Deflation, deflate_level, mask_deflation
from heoslice.volume import load_volume

CENTRE, TUMOUR_CENTRE, RADIUS, TUMOUR_RADIUS = np.array([0.3, -0.2, 40.1]), np.array([5.2, 3.1, 42.0]), 20.0, 6.0

MATERIALS = """
[materials.tissue]
color = "#c04030"
channel = 1
[materials.cells]
color = "#30c040"
channel = 2
[materials.tumour]
color = "#3040c0"
channel = 3
[labels]
1 = "tissue"
2 = "tumour"
[grade.1]
to = "cells"
{grade}
"""


def organ(tmp_path, names: tuple[str, str] | None = None):
    """The liver (label 1) holding the tumour (label 2), 1 mm voxels, centres off the voxel grid; with
    ``names``, a .seg.nrrd whose two segments have those names."""
    affine = grid_affine(1.0, [-24.0, -24.0, 16.0])
    points = voxel_centres((49, 49, 49), affine)
    data = np.zeros((49, 49, 49), np.uint8)
    data[np.linalg.norm(points - CENTRE, axis=-1) <= RADIUS] = 1
    data[np.linalg.norm(points - TUMOUR_CENTRE, axis=-1) <= TUMOUR_RADIUS] = 2
    if names is None:
        return load_volume(write_nifti(tmp_path / "organ.nii.gz", data, affine))
    segments = {f"Segment{n}_{key}": value for n, name in enumerate(names)
                for key, value in (("Name", name), ("LabelValue", str(n + 1)), ("Layer", "0"))}
    return load_volume(write_nrrd(tmp_path / "organ.seg.nrrd", data, FLIP_XY @ affine, segments))


def sliced(tmp_path, grade: str):
    path = tmp_path / "mats.toml"
    path.write_text(MATERIALS.format(grade=grade))
    table = read_materials_file(path)
    volume = organ(tmp_path)
    plan = plan_labels(volume, table.materials, table.labels())
    grades = read_grades(table.data["grade"], table.materials, f"{path}: [grade]")
    spec = SliceSpec(layer_height_mm=1.0, dpi=(150.0, 150.0), jobs=1)
    manifest, _ = slice_volume_to_stack(volume, tmp_path / "stack", spec, plan, grades=grades)
    return manifest


@pytest.mark.parametrize("case", ["toward the tumour", "from its own boundary"])
def test_share_per_band_of_distance_follows_the_design(tmp_path, case):
    if case == "toward the tumour":
        manifest = sliced(tmp_path, 'toward = 2\nrange = [0.0, 12.0]')
        def distance(p):
            return np.linalg.norm(p - TUMOUR_CENTRE, axis=-1) - TUMOUR_RADIUS
        design = lambda d: np.clip(d / 12.0, 0, 1)  # noqa: E731 - linear f(r), r = d / 12 mm
        bands = np.arange(0.0, 14.0, 2.0)
    else:
        manifest = sliced(tmp_path, 'function = "quadratic"\nrange = [0.0, 10.0]')
        def distance(p):  # the label's own boundary: the sphere's, and the tumour's cavity inside it
            return np.minimum(RADIUS - np.linalg.norm(p - CENTRE, axis=-1),
                              np.linalg.norm(p - TUMOUR_CENTRE, axis=-1) - TUMOUR_RADIUS)
        design = lambda d: np.clip(d / 10.0, 0, 1) ** 2  # noqa: E731 - quadratic f(r) = r^2
        bands = np.arange(0.0, 10.0, 2.0)  # the deepest point is about 10 mm deep
    names = [entry["name"] for entry in manifest["grading"]["materials"]]
    assert names == ["tissue", "cells", "tumour"]
    record = manifest["labels"][0]["grading"]
    assert record["to"] == "cells" and record["toward"] == ("2" if case == "toward the tumour" else "1")
    width, height = manifest["image"]["width"], manifest["image"]["height"]
    x_left, y_top = manifest["image"]["origin_mm"]
    px, py = manifest["pixel_size_mm"]
    x = x_left + (np.arange(width) + 0.5) * px
    y = y_top - (np.arange(height) + 0.5) * py
    delivered, wanted, pixels = np.zeros(len(bands) - 1), np.zeros(len(bands) - 1), np.zeros(len(bands) - 1)
    for index, entry in enumerate(manifest["layers"]):
        solid = read_layer_mask(tmp_path / "stack", manifest, index).astype(bool)
        masks = read_layer_channels(tmp_path / "stack", manifest, index).astype(bool)
        assert np.array_equal(masks.sum(axis=0), solid.astype(int))
        graded = masks[0] | masks[1]
        rows, columns = np.nonzero(graded)
        d = distance(np.column_stack([x[columns], y[rows], np.full(len(rows), entry["z_mm"])]))
        outer = np.linalg.norm(np.column_stack([x[columns], y[rows], np.full(len(rows), entry["z_mm"])]) - CENTRE,
                               axis=-1)
        keep = outer < RADIUS - 1.0  # off the reconstructed outer boundary by a voxel
        band = np.digitize(d[keep], bands) - 1
        inside = (band >= 0) & (band < len(bands) - 1)
        np.add.at(pixels, band[inside], 1)
        np.add.at(wanted, band[inside], design(d[keep][inside]))
        np.add.at(delivered, band[inside], masks[1][rows, columns][keep][inside])
    assert pixels.min() > 2000
    share, target = delivered / pixels, wanted / pixels
    assert np.abs(share - target).max() <= 0.02, (share.round(4), target.round(4))


def test_grading_needs_a_printed_label_and_a_known_reference(tmp_path):
    """Each [grade] mistake is an InputError naming it: an unknown ``toward``, a bad range, a label that exists
    but is not printed, a label graded by two keys (its value and its name), a ``toward`` naming two labels."""
    for grade, words in (('toward = 7', "toward 7: no such label"), ('range = [5.0, 1.0]', "range must be")):
        with pytest.raises(InputError, match=words):
            sliced(tmp_path, grade)
    path = tmp_path / "mats.toml"
    path.write_text(MATERIALS.format(grade=""))
    table = read_materials_file(path)
    volume = organ(tmp_path, ("liver", "tumour"))
    plan = plan_labels(volume, table.materials, table.labels())
    starts = [plan.materials[material] for material in plan.label_material]

    def resolve(entries: dict, labels=plan.labels):
        return resolve_grades(read_grades(entries, table.materials, "m: [grade]"), volume, labels, starts)

    with pytest.raises(InputError, match=r"\[grade\] tumour: the label is not printed \(list it in \[labels\]\)"):
        resolve({"tumour": {"to": "cells"}}, plan.labels[:1])
    with pytest.raises(InputError, match=r"\[grade\]: label 1 liver is graded twice"):
        resolve({"1": {"to": "cells"}, "liver": {"to": "cells"}})
    twins = organ(tmp_path, ("organ", "organ"))
    with pytest.raises(InputError, match=r"toward organ: names 2 labels \(1 organ, 2 organ\); name one"):
        resolve_grades(read_grades({"1": {"to": "cells", "toward": "organ"}}, table.materials, "m: [grade]"), twins,
                       twins.labels, starts)


def test_a_key_naming_two_labels_grades_each_from_its_own_surface(tmp_path):
    """[grade.organ] naming both segments (liver and tumour share the name) grades each from its own boundary:
    each label's record names itself as the reference, and the tumour's pixels within 1 mm of its own surface
    get little of the target (r near 0) while its centre gets most (were it measured from the liver's surface,
    about 8 .. 20 mm away, all of them would be near 1)."""
    path = tmp_path / "mats.toml"
    path.write_text(MATERIALS.split("[labels]")[0] + '[labels]\norgan = "tissue"\n[grade.organ]\nto = "cells"\n'
                    'range = [0.0, 5.0]\n')
    table = read_materials_file(path)
    volume = organ(tmp_path, ("organ", "organ"))
    plan = plan_labels(volume, table.materials, table.labels())
    grades = read_grades(table.data["grade"], table.materials, f"{path}: [grade]")
    spec = SliceSpec(layer_height_mm=1.0, dpi=(100.0, 100.0), jobs=1)
    manifest, _ = slice_volume_to_stack(volume, tmp_path / "stack", spec, plan, grades=grades)
    assert [entry["grading"]["toward"] for entry in manifest["labels"]] == ["1 organ", "2 organ"]
    x_left, y_top = manifest["image"]["origin_mm"]
    px, py = manifest["pixel_size_mm"]
    near, deep = [], []
    for index, entry in enumerate(manifest["layers"]):
        masks = read_layer_channels(tmp_path / "stack", manifest, index).astype(bool)
        rows, columns = np.nonzero(masks[0] | masks[1])
        points = np.column_stack([x_left + (columns + 0.5) * px, y_top - (rows + 0.5) * py,
                                  np.full(len(rows), entry["z_mm"])])
        depth = TUMOUR_RADIUS - np.linalg.norm(points - TUMOUR_CENTRE, axis=-1)
        target = masks[1][rows, columns]
        near.extend(target[(depth > 0.3) & (depth < 1.0)])
        deep.extend(target[depth > 5.0])
    assert len(near) > 500 and len(deep) > 20
    assert np.mean(near) < 0.3 and np.mean(deep) > 0.8, (np.mean(near), np.mean(deep))


def test_halftone_option_halftones_graded_labels_and_is_recorded(tmp_path, capsys):
    """``slice MAP --halftone blue-noise`` reaches the graded label's droplets: the same solid masks, other
    droplet masks than the default's, and the manifest's grading.halftone says blue-noise (the default,
    ordered, leaves the field out as the mesh route does); both stacks verify."""
    (tmp_path / "mats.toml").write_text(MATERIALS.format(grade="toward = 2"))
    organ(tmp_path)
    manifests = {}
    for method in ("ordered", "blue-noise"):
        assert in_process("slice", tmp_path / "organ.nii.gz", "--materials", tmp_path / "mats.toml", "--layer", "2",
                          "--dpi", "50", "--halftone", method, "-o", tmp_path / method) == 0
        assert in_process("verify", tmp_path / method) == 0
        manifests[method] = json.loads((tmp_path / method / "manifest.json").read_text())
    ordered, blue = manifests["ordered"], manifests["blue-noise"]
    assert "halftone" not in ordered["grading"] and blue["grading"]["halftone"] == "blue-noise"
    assert [layer["sha256"] for layer in ordered["layers"]] == [layer["sha256"] for layer in blue["layers"]]
    droplets = lambda manifest: [[c["sha256"] for c in layer["channels"]] for layer in manifest["layers"]]  # noqa: E731
    assert droplets(ordered) != droplets(blue)
    for method, manifest in manifests.items():  # the masks deflated as their halftone says, as the mesh route's
        for layer in manifest["layers"]:
            for name, way in ((layer["file"], Deflation("zlib-ng", deflate_level(True))),
                              *((c["file"], mask_deflation(method)) for c in layer["channels"])):
                path = tmp_path / method / name
                with tifffile.TiffFile(path) as tiff:
                    pixels, spacing = tiff.pages.first.asarray(), tiff.imagej_metadata["spacing"]
                assert path.read_bytes() == encode_bilevel_tiff(np.packbits(pixels, axis=1), pixels.shape[1],
                                                                tuple(manifest["dpi"]), "deflate", spacing,
                                                                level=way.level, encoder=way.encoder), path.name


def test_slice_cli_grades_a_label_and_verify_passes(tmp_path, capsys):
    """``heoslice slice MAP --materials`` with a [grade] table: the label's record names its grading, the
    droplet masks are the three materials, and the stack verifies; [grade] with a CT is a one-line error."""
    (tmp_path / "mats.toml").write_text(MATERIALS.format(grade="toward = 2"))
    organ(tmp_path)
    code = in_process("slice", tmp_path / "organ.nii.gz", "--materials", tmp_path / "mats.toml", "--layer", "2",
                      "--dpi", "50", "-o", tmp_path / "out", "--json")
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["materials"] == ["tissue", "cells", "tumour"] and out["droplet_masks"]
    grading = out["labels"][0]["grading"]
    assert grading["toward"] == "2" and grading["range_mm"][0] == 0.0 and grading["range_mm"][1] > 10.0
    assert in_process("verify", tmp_path / "out") == 0
    assert in_process("slice", tmp_path / "organ.nii.gz", "--as", "intensity", "--materials", tmp_path / "mats.toml",
                      "-o", tmp_path / "ct") == 2
    assert "[grade] grades labels of a label map" in capsys.readouterr().err
