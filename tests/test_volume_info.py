"""``info`` on volumes: shape, voxel size, orientation, extent and per-label voxels and volume, against what
the test wrote."""

from __future__ import annotations

import json

import numpy as np
from helpers import in_process
from volume_phantoms import FLIP_XY, grid_affine, write_nifti, write_nrrd

from heoslice.volume import load_volume
from heoslice.volume.info import volume_info


def test_label_counts_volumes_extent_and_orientation(tmp_path):
    """Counts and volumes are the voxels written x the voxel volume; the extent is the voxel box +- half a voxel;
    a RAS NIfTI and the LPS NRRD of the same voxels have the same orientation letters."""
    data = np.zeros((10, 8, 6), np.uint8)
    data[1:4, 1:3, 1:2] = 3
    data[5, 5, 5] = 8
    affine = grid_affine(2.0, [10.0, 20.0, 30.0])
    summary = volume_info(load_volume(write_nifti(tmp_path / "a.nii.gz", data, affine)))
    assert summary["shape"] == [10, 8, 6] and summary["voxel_size_mm"] == [2.0, 2.0, 2.0]
    assert [(label["value"], label["voxels"]) for label in summary["labels"]] == [(3, 6), (8, 1)]
    assert np.allclose([label["volume_mm3"] for label in summary["labels"]], [48.0, 8.0])
    assert np.allclose(summary["extent_mm"], [[9.0, 19.0, 29.0], [29.0, 35.0, 41.0]])
    assert summary["orientation"] == "RAS"
    lps = volume_info(load_volume(write_nrrd(tmp_path / "a.nrrd", data, FLIP_XY @ affine)))
    assert lps["orientation"] == "RAS" and lps["space"] == "LPS"
    assert np.allclose(lps["extent_mm"], [[-29.0, -35.0, 29.0], [-9.0, -19.0, 41.0]])


def test_flipped_axes_give_their_letters(tmp_path):
    """An i axis pointing left and a k axis pointing inferior read as 'LAI'."""
    affine = np.diag([-1.0, 1.0, -2.0, 1.0])
    summary = volume_info(load_volume(write_nifti(tmp_path / "a.nii", np.ones((2, 2, 2), np.uint8), affine)))
    assert summary["orientation"] == "LAI"


def test_info_cli_json_on_a_label_map(tmp_path, capsys):
    data = np.zeros((4, 4, 4), np.uint8)
    data[1, 1, 1] = 13
    path = write_nifti(tmp_path / "seg.nii.gz", data, grid_affine(3.0, [0, 0, 0]))
    assert in_process("info", path, "--json") == 0
    out = json.loads(capsys.readouterr().out)
    (label,) = out["labels"]
    assert out["ok"] and (label["value"], label["name"], label["voxels"]) == (13, None, 1)
    assert abs(label["volume_mm3"] - 27.0) < 1e-9


def test_info_cli_names_the_bad_file_in_one_line(tmp_path, capsys):
    path = tmp_path / "bad.nii.gz"
    path.write_bytes(b"not a nifti")
    assert in_process("info", path) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("heoslice: error:") and str(path) in err and "\n" not in err


def test_shared_label_map_info(shared_data):
    """The shared 41-label map: 122 x 101 x 30 voxels of 3 mm, RAS, liver (5) 38,634 voxels, label 13 one."""
    summary = volume_info(load_volume(shared_data / "imaging" / "example_seg.nii.gz"))
    assert summary["shape"] == [122, 101, 30] and summary["orientation"] == "RAS"
    counts = {label["value"]: label["voxels"] for label in summary["labels"]}
    assert len(counts) == 41 and counts[5] == 38634 and counts[13] == 1
    assert all(label["name"] is None for label in summary["labels"])  # the file has no names: none invented
