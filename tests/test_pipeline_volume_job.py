"""The volume route's slice job: [labels] choose what prints in which material; every solid pixel is in exactly
one droplet mask; a label of one voxel prints; the manifest records the placement; RAS and LPS files of the
same labels give the same stack; the stack passes verify."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import heoslice, in_process
from volume_phantoms import FLIP_XY, grid_affine, write_nifti, write_nrrd

from heoslice.errors import InputError
from heoslice.material import DEFAULT_MATERIALS, Material, PartSetting, read_materials_file
from heoslice.pipeline import SliceSpec
from heoslice.pipeline.volume_job import plan_labels, slice_volume_to_stack
from heoslice.stack import read_layer_channels, read_layer_mask, verify_stack
from heoslice.volume import load_volume

MATERIALS = """
[materials.gel]
color = "#f0f0f0"
channel = 1
[materials.cells]
color = "0,255,0"
channel = 2
[labels]
{labels}
"""


def organ_map() -> np.ndarray:
    """Two touching organs (labels 4 and 7), a one-voxel label 9 inside organ 4, and label 11 unlisted."""
    data = np.zeros((14, 12, 10), np.uint8)
    data[2:8, 2:9, 2:8] = 4
    data[8:12, 2:9, 2:8] = 7
    data[4, 5, 4] = 9
    data[12, 10, 8] = 11
    return data


def materials(tmp_path, labels: str):
    path = tmp_path / "mats.toml"
    path.write_text(MATERIALS.format(labels=labels))
    return read_materials_file(path)


def slice_map(tmp_path, volume, table, name="stack", dpi=150.0, jobs=0):
    plan = plan_labels(volume, table.materials, table.labels() if table.has_labels else None)
    spec = SliceSpec(layer_height_mm=0.5, dpi=(dpi, dpi), jobs=jobs)
    manifest, _ = slice_volume_to_stack(volume, tmp_path / name, spec, plan)
    return manifest, plan


def test_masks_partition_the_solid_and_the_one_voxel_label_prints(tmp_path):
    """Each solid pixel is in exactly one droplet mask; the one-voxel label 9 (inside organ 4, same material as
    organ 7) has pixels: it is the only label in 'cells'; unlisted label 11 prints nowhere."""
    volume = load_volume(write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0])))
    manifest, plan = slice_map(tmp_path, volume, materials(tmp_path, '4 = "gel"\n7 = "gel"\n9 = "cells"'))
    assert [label.value for label in plan.labels] == [4, 7, 9]
    cells = 0
    for entry in manifest["layers"]:
        solid = read_layer_mask(tmp_path / "stack", manifest, entry["index"]).astype(bool)
        masks = read_layer_channels(tmp_path / "stack", manifest, entry["index"]).astype(bool)
        assert np.array_equal(masks.sum(axis=0), solid.astype(int))
        cells += int(masks[1].sum())
    assert cells > 0
    voxel = 8.0
    pixel_volume = manifest["pixel_size_mm"][0] * manifest["pixel_size_mm"][1] * manifest["layer_height_mm"]
    assert abs(cells * pixel_volume - voxel) < 0.35 * voxel  # one voxel's volume, at this coarse resolution
    report = verify_stack(tmp_path / "stack")
    assert report.ok, report.problems


def test_label_11_left_out_when_unlisted(tmp_path):
    """Only listed labels print: the stack's volume is that of labels 4 and 7, not 11's corner voxel."""
    volume = load_volume(write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0])))
    with_11, _ = slice_map(tmp_path, volume, materials(tmp_path, '4 = "gel"\n7 = "gel"\n11 = "gel"'), "a")
    without, _ = slice_map(tmp_path, volume, materials(tmp_path, '4 = "gel"\n7 = "gel"'), "b")
    solid = lambda manifest: sum(entry["solid_pixels"] for entry in manifest["layers"])  # noqa: E731
    assert solid(with_11) > solid(without)
    assert [label["value"] for label in without["labels"]] == [4, 7]


def test_touching_labels_leave_no_crack(tmp_path):
    """Where organs 4 and 7 touch (x = 16 mm), every pixel between them is solid: the union's field fills
    the seam whatever each label's own level."""
    volume = load_volume(write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0])))
    manifest, _ = slice_map(tmp_path, volume, materials(tmp_path, '4 = "gel"\n7 = "cells"'))
    middle = len(manifest["layers"]) // 2
    solid = read_layer_mask(tmp_path / "stack", manifest, middle).astype(bool)
    left, top = manifest["image"]["origin_mm"]
    px, py = manifest["pixel_size_mm"]
    row = int((top - 11.0) / py)  # y = 11 mm: inside both organs (voxels j 2..8, 4..16 mm)
    columns = [int((x - left) / px) for x in np.linspace(8.0, 20.0, 60)]
    assert solid[row, columns].all()


def test_listed_label_missing_from_the_file_is_one_line(tmp_path):
    volume = load_volume(write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0])))
    table = materials(tmp_path, '4 = "gel"\n42 = "gel"')
    with pytest.raises(InputError, match=r"\[labels\] 42: no such label"):
        plan_labels(volume, table.materials, table.labels())


def test_labels_by_segment_name(tmp_path):
    """A .seg.nrrd's segments are named in [labels] by name, case ignored."""
    extra = {"Segment0_Name": "Liver", "Segment0_LabelValue": "4", "Segment0_Layer": "0",
             "Segment1_Name": "tumour", "Segment1_LabelValue": "9", "Segment1_Layer": "0"}
    volume = load_volume(write_nrrd(tmp_path / "s.seg.nrrd", organ_map(), FLIP_XY @ grid_affine(2.0, [0, 0, 0]),
                                    extra))
    table = materials(tmp_path, '"liver" = "gel"\n"tumour" = "cells"')
    plan = plan_labels(volume, table.materials, table.labels())
    assert [(label.value, label.name) for label in plan.labels] == [(4, "Liver"), (9, "tumour")]


def test_ras_and_lps_files_give_the_same_stack(tmp_path):
    """The same labels stored as a RAS NIfTI and as an LPS NRRD slice into identical layer images."""
    data, affine = organ_map(), grid_affine(2.0, [3.0, -5.0, 7.0])
    table = read_materials_file(None)
    ras = load_volume(write_nifti(tmp_path / "m.nii.gz", data, affine))
    lps = load_volume(write_nrrd(tmp_path / "m.nrrd", data, FLIP_XY @ affine))
    first, _ = slice_map(tmp_path, ras, table, "ras")
    second, _ = slice_map(tmp_path, lps, table, "lps")
    assert [entry["sha256"] for entry in first["layers"]] == [entry["sha256"] for entry in second["layers"]]
    assert first["image"] == second["image"] and first["z_range_mm"] == second["z_range_mm"]


def test_worker_processes_write_the_stack_one_process_writes(tmp_path):
    """The layers rendered over two worker processes are byte for byte those of one process, solid mask and
    droplet masks, and the manifests list them in the same order."""
    volume = load_volume(write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0])))
    table = materials(tmp_path, '4 = "gel"\n7 = "cells"\n9 = "cells"')
    one, _ = slice_map(tmp_path, volume, table, "one", jobs=1)
    two, _ = slice_map(tmp_path, volume, table, "two", jobs=2)
    assert len(one["layers"]) > 10
    assert json.dumps(one["layers"]) == json.dumps(two["layers"])


def test_placement_maps_the_print_back_to_the_scan(tmp_path):
    """The manifest's placement takes printer mm back to scan mm: for an LPS file, x and y negated; its
    recorded origin is the first image's top-left corner at the lowest layer."""
    data, affine = organ_map(), FLIP_XY @ grid_affine(2.0, [3.0, -5.0, 7.0])
    volume = load_volume(write_nrrd(tmp_path / "m.nrrd", data, affine))
    manifest, _ = slice_map(tmp_path, volume, read_materials_file(None))
    placement = manifest["placement"]
    assert placement["space"] == "LPS" and placement["up"] == "S"
    assert np.allclose(placement["printer_from_scan"], np.diag([-1.0, -1.0, 1.0, 1.0]))
    left, top = manifest["image"]["origin_mm"]
    assert np.allclose(placement["print_origin_in_scan_mm"], [-left, -top, manifest["z_range_mm"][0]])


def test_up_axis_turns_the_print(tmp_path):
    """With --up A the stack's height spans the volume's anterior axis: a box 4 voxels deep in y (6 in z) spans
    4 voxels plus half a voxel either side (a reconstructed surface may bulge past a voxel face): 10 mm."""
    data = np.zeros((8, 8, 8), np.uint8)
    data[2:6, 2:6, 1:7] = 1
    volume = load_volume(write_nifti(tmp_path / "b.nii.gz", data, grid_affine(2.0, [0, 0, 0])))
    plan = plan_labels(volume, dict(DEFAULT_MATERIALS), None)
    manifest, _ = slice_volume_to_stack(volume, tmp_path / "up", SliceSpec(layer_height_mm=0.5, dpi=(100, 100)), plan,
                                        up="A")
    low, high = manifest["z_range_mm"]
    assert abs((high - low) - (4 + 1) * 2.0) < 1e-9


def test_slice_cli_on_a_label_map(tmp_path, capsys):
    """``heoslice slice MAP --materials`` writes a verified stack and reports its labels in JSON."""
    path = write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "mats.toml").write_text(MATERIALS.format(labels='4 = "gel"\n9 = "cells"'))
    code = in_process("slice", path, "--materials", tmp_path / "mats.toml", "--layer", "0.5", "--dpi", "100", "-o",
                      tmp_path / "out", "--json")
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert [label["value"] for label in out["labels"]] == [4, 9] and out["droplet_masks"]
    assert in_process("verify", tmp_path / "out") == 0


def test_verify_against_the_label_map(tmp_path, capsys):
    """verify --mesh MAP compares the stack's volume with the printed labels' voxel volume: within 1 % for the
    map it came from (organ 4 alone: two touching box-shaped labels each lose the bulge that keeps their
    rounded corners' volume, about 2 % here); against another file (its digest differs: a warning) whose
    labels hold less, a problem (exit 4)."""
    path = write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "mats.toml").write_text(MATERIALS.format(labels='4 = "gel"'))
    assert in_process("slice", path, "--materials", tmp_path / "mats.toml", "--layer", "0.25", "--dpi", "200", "-o",
                      tmp_path / "out") == 0
    capsys.readouterr()
    assert in_process("verify", tmp_path / "out", "--mesh", path, "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert abs(summary["mesh"]["volume_mm3"] - (6 * 7 * 6 - 1) * 8.0) < 1e-6
    assert abs(summary["mesh"]["relative_volume_difference"]) <= 0.01
    other = organ_map()
    other[2:4][other[2:4] == 4] = 0
    smaller = write_nifti(tmp_path / "other.nii.gz", other, grid_affine(2.0, [0, 0, 0]))
    assert in_process("verify", tmp_path / "out", "--mesh", smaller, "--json") == 4
    summary = json.loads(capsys.readouterr().out)
    assert summary["warnings"] and summary["problems"]


def test_droplet_masks_follow_channel_then_table_order(tmp_path):
    """The droplet masks' order is the one rule of ``_mask_order``: by printer channel, materials without one
    (a table not read from a file, whose reader gives each a free channel) last, ties by the table's order,
    whatever order [labels] names them in."""
    table = {name: Material(name, color, channel) for name, color, channel in (
        ("gel", (240, 240, 240), None), ("wax", (160, 160, 160), None), ("cells", (0, 255, 0), 2))}
    settings = {"4": PartSetting("wax"), "7": PartSetting("gel"), "9": PartSetting("cells")}  # wax seen first
    volume = load_volume(write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0])))
    plan = plan_labels(volume, table, settings)
    assert [material.name for material in plan.materials] == ["cells", "gel", "wax"]
    assert [plan.materials[index].name for index in plan.label_material] == ["wax", "gel", "cells"]  # labels 4, 7, 9
    manifest, _ = slice_volume_to_stack(volume, tmp_path / "stack", SliceSpec(layer_height_mm=1.0, dpi=(50, 50)), plan)
    assert [entry["name"] for entry in manifest["grading"]["materials"]] == ["cells", "gel", "wax"]


def test_a_printer_preset_pads_a_label_maps_stack_and_limits_its_materials(tmp_path):
    """``slice MAP --printer connex-30um``: the volume route's stack is on the preset's grid (600 x 300 dpi, 0.03 mm
    layers, width a multiple of 16 px where the map's own width is not), and a table of more materials than the
    preset jets (Connex3: 3) is one line, exit 2."""
    path = write_nifti(tmp_path / "m.nii.gz", organ_map(), grid_affine(2.0, [0, 0, 0]))
    (tmp_path / "mats.toml").write_text(MATERIALS.format(labels='4 = "gel"\n9 = "cells"'))
    assert in_process("slice", path, "--materials", tmp_path / "mats.toml", "--printer", "connex-30um",
                      "-o", tmp_path / "preset") == 0
    assert in_process("slice", path, "--materials", tmp_path / "mats.toml", "--layer", "0.03", "--dpi", "600x300",
                      "-o", tmp_path / "plain") == 0
    preset, plain = (json.loads((tmp_path / name / "manifest.json").read_text()) for name in ("preset", "plain"))
    assert preset["dpi"] == [600.0, 300.0] and preset["layer_height_mm"] == 0.03
    assert plain["image"]["width"] % 16 != 0
    assert preset["image"]["width"] == -(-plain["image"]["width"] // 16) * 16
    four = MATERIALS.format(labels='4 = "gel"\n7 = "cells"\n9 = "bone"\n11 = "fat"') + """
[materials.bone]
color = "#ffffff"
channel = 3
[materials.fat]
color = "#ffff00"
channel = 4
"""
    (tmp_path / "four.toml").write_text(four)
    done = heoslice("slice", path, "--materials", tmp_path / "four.toml", "--printer", "connex-30um",
                    "-o", tmp_path / "four")
    assert done.returncode == 2 and "connex-30um jets at most 3" in done.stderr, done.stderr
    assert done.stderr.count("\n") == 1 and not (tmp_path / "four").exists()
