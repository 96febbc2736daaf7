"""Tests of cli/volume.py: what the materials file asks of a volume is done or refused in one line (a [labels]
table or [intensity] 'within' that would be ignored, number keys for a folder of structures, a guessed label
map of many values), and the reader's warnings are shown."""

from __future__ import annotations

from pathlib import Path

import nibabel as nib
import numpy as np
from helpers import CT_CURVE, CT_MATERIALS

from heoslice.errors import EXIT_INPUT

FAST = ["--dpi", "50", "--layer", "1", "-j", "1"]
MATERIALS, CURVE = CT_MATERIALS, CT_CURVE


def nifti(path: Path, data: np.ndarray, affine=None) -> Path:
    nib.save(nib.Nifti1Image(data, np.diag([2.0, 2.0, 2.0, 1.0]) if affine is None else affine), str(path))
    return path


def ct(path: Path) -> Path:
    hu = np.full((8, 8, 6), -1000, np.int16)
    hu[2:6, 2:6, 1:5] = 500
    return nifti(path, hu)


def organs(path: Path) -> Path:
    data = np.zeros((8, 8, 6), np.uint8)
    data[2:6, 2:6, 1:5] = 1
    data[6:8, 6:8, 1:5] = 2
    return nifti(path, data)


def materials(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "m.toml"
    path.write_text(MATERIALS + text)
    return path


def refused(run_cli, tmp_path, *args) -> str:
    """Run slice, check it is one error line, exit 2, nothing written; the line."""
    code, out, err = run_cli("slice", *args, "-o", tmp_path / "out", *FAST)
    assert code == EXIT_INPUT and out == "" and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()
    return err


def test_within_without_labels_is_refused(run_cli, tmp_path):
    """[intensity] within with a CT but no --labels would be ignored: one line naming the file and --labels."""
    path = materials(tmp_path, CURVE + "within = [1]\n")
    err = refused(run_cli, tmp_path, ct(tmp_path / "ct.nii.gz"), "--materials", path)
    assert f"{path}: [intensity] within" in err and "--labels MAP" in err


def test_labels_table_for_a_ct_without_labels_is_refused(run_cli, tmp_path):
    """A [labels] table with a CT and no --labels would be ignored: one line naming the file and --labels."""
    path = materials(tmp_path, CURVE + '[labels]\n1 = "tissue"\n')
    err = refused(run_cli, tmp_path, ct(tmp_path / "ct.nii.gz"), "--materials", path)
    assert f"{path}: [labels]" in err and "intensity volume" in err and "--labels MAP" in err


def test_mesh_options_with_a_volume_are_refused(run_cli, tmp_path):
    """--rgba (a preview stack) and --interior (a coloured mesh's interior) would be ignored for a volume, whose
    stack is a print job of its labels: each is one line naming it, nothing written."""
    for flags in (("--rgba",), ("--interior", "contour")):
        err = refused(run_cli, tmp_path, organs(tmp_path / "seg.nii.gz"), *flags)
        assert flags[0] in err and "do not apply" in err


def test_a_defaults_files_mesh_settings_leave_a_volume_alone(run_cli, tmp_path):
    """A defaults file's [slice] interior and --rgba (channels = false), there for the lab's coloured meshes, do not
    stop a volume's slice (they are refused only when typed for it): it slices its labels, a print job."""
    (tmp_path / "heoslice.toml").write_text('[slice]\ninterior = "contour"\nchannels = false\n')
    code, _, err = run_cli("--config", tmp_path / "heoslice.toml", "slice", organs(tmp_path / "seg.nii.gz"), "-o",
                           tmp_path / "out", *FAST)
    assert code == 0, err
    assert (tmp_path / "out" / "manifest.json").exists()


def test_ct_with_its_curve_alone_still_slices(run_cli, tmp_path):
    """The refusals above leave the plain CT-by-curve job alone."""
    code, _, err = run_cli("slice", ct(tmp_path / "ct.nii.gz"), "--materials", materials(tmp_path, CURVE), "-o",
                           tmp_path / "out", *FAST)
    assert code == 0, err


def structure_folder(tmp_path: Path) -> Path:
    """A folder of two structures, 'aorta' (file position 1) and 'liver' (file position 2)."""
    folder = tmp_path / "structures"
    folder.mkdir()
    for name, box in (("liver", (slice(2, 6), slice(2, 6), slice(1, 5))), ("aorta", (6, 6, slice(1, 5)))):
        mask = np.zeros((8, 8, 6), np.uint8)
        mask[box] = 1
        nifti(folder / f"{name}.nii.gz", mask)
    return folder


def test_number_keys_for_a_structure_folder_are_refused(run_cli, tmp_path):
    """[labels] 2 = ... for a folder would pick whichever file sorts second: refused, saying to use names."""
    folder = structure_folder(tmp_path)
    path = materials(tmp_path, '[labels]\n2 = "tissue"\n')
    err = refused(run_cli, tmp_path, folder, "--materials", path)
    assert f"{path}: [labels]: 2:" in err and "name the structure instead" in err


def test_number_keys_in_within_for_a_structure_folder_are_refused(run_cli, tmp_path):
    folder = structure_folder(tmp_path)
    path = materials(tmp_path, CURVE + "within = [1]\n")
    err = refused(run_cli, tmp_path, ct(tmp_path / "ct.nii.gz"), "--labels", folder, "--materials", path)
    assert "1:" in err and "name the structure instead" in err


def test_structure_names_for_a_folder_slice(run_cli, tmp_path):
    """Names select a folder's structures: liver prints, and only liver."""
    import json

    path = materials(tmp_path, '[labels]\nliver = "tissue"\n')
    code, out, err = run_cli("slice", structure_folder(tmp_path), "--materials", path, "-o", tmp_path / "out",
                             "--json", *FAST)
    assert code == 0, err
    assert [label["name"] for label in json.loads(out)["labels"]] == ["liver"]


def test_guessed_label_map_of_many_values_without_labels_is_refused(run_cli, tmp_path):
    """An 8-bit CT guessed a label map of many values, with no [labels] table, would print as one block:
    refused with the advice --as intensity; --as labels slices it."""
    from heoslice.volume.readers import GUESS_WARN_LABELS

    data = np.arange(8 * 8 * 6, dtype=np.uint16).reshape(8, 8, 6) % 200
    assert len(np.unique(data)) - 1 > GUESS_WARN_LABELS
    path = nifti(tmp_path / "ct8.nii.gz", data)
    err = refused(run_cli, tmp_path, path, "--materials", materials(tmp_path, ""))
    assert "--as intensity" in err and f"{path}:" in err
    code, _, err = run_cli("slice", path, "--as", "labels", "--materials", materials(tmp_path, ""), "-o",
                           tmp_path / "out", *FAST)
    assert code == 0, err


def test_negative_label_values_are_one_line(run_cli, tmp_path):
    """--as labels on a map holding a negative value is one line naming the file (no IndexError)."""
    data = np.zeros((8, 8, 6), np.int16)
    data[2:6, 2:6, 1:5] = 1
    data[0, 0, 0] = -1
    path = nifti(tmp_path / "neg.nii.gz", data)
    err = refused(run_cli, tmp_path, path, "--as", "labels", "--materials", materials(tmp_path, ""))
    assert f"{path}: 1 voxel(s) of negative value" in err


def test_missing_orientation_warned_by_slice_and_info(run_cli, tmp_path):
    """A NIfTI with neither sform nor qform slices with a warning line, and info shows it."""
    data = np.zeros((8, 8, 6), np.uint8)
    data[2:6, 2:6, 1:5] = 1
    path = tmp_path / "bare.nii.gz"
    nib.save(nib.Nifti1Image(data, None), str(path))
    code, _, err = run_cli("slice", path, "--materials", materials(tmp_path, ""), "-o", tmp_path / "out", *FAST)
    assert code == 0 and "left/right cannot be trusted" in err
    code, out, _ = run_cli("info", path)
    assert code == 0 and "left/right cannot be trusted" in out


def test_a_label_maps_warnings_are_printed_under_its_own_name(run_cli, tmp_path):
    """A CT with an orientation and a label map without one (sform and qform codes 0): the label map's warning
    names the label map, not the CT."""
    image = nib.Nifti1Image(np.asarray(nib.load(str(organs(tmp_path / "l.nii.gz"))).dataobj), None)
    image.set_sform(None, code=0)
    image.set_qform(None, code=0)
    bare = tmp_path / "bare.nii.gz"
    nib.save(image, str(bare))
    path = materials(tmp_path, CURVE + "within = [1]\n")
    code, _, err = run_cli("slice", ct(tmp_path / "ct.nii.gz"), "--labels", bare, "--materials", path, "-o",
                           tmp_path / "out", *FAST)
    lines = [line for line in err.splitlines() if "no orientation" in line]
    assert lines and all(line.startswith(f"warning: {bare}: ") for line in lines), err
