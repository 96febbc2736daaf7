"""Volume readers: each format gives the same typed Volume (voxels, affine, space, labels); sizes, affines and
values a file should not have are one-line InputErrors (exit 2)."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
from conftest import shared_data_dir
from volume_phantoms import FLIP_XY, grid_affine, write_dicom_series, write_nifti, write_nrrd

from heoslice.errors import InputError
from heoslice.volume import load_volume
from heoslice.volume.model import MAX_VOLUME_BYTES

IMAGING = shared_data_dir() / "imaging"


def labels_array(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    data = np.zeros((9, 8, 7), dtype=np.uint8)
    data[2:6, 2:5, 1:4] = 5
    data[6:8, 1:3, 4:6] = 7
    data[rng.integers(0, 9), rng.integers(0, 8), 6] = 9
    return data


def test_nifti_labels_keep_values_affine_and_ras(tmp_path):
    """A NIfTI label map reads back voxel for voxel, with its affine, in RAS, its labels its non-zero values."""
    data, affine = labels_array(), grid_affine(1.5, [10.0, -20.0, 30.0])
    volume = load_volume(write_nifti(tmp_path / "seg.nii.gz", data, affine))
    assert volume.kind == "labels" and volume.space == "RAS"
    assert np.array_equal(volume.data, data) and np.allclose(volume.affine, affine)
    assert [label.value for label in volume.labels] == sorted(set(np.unique(data)) - {0})


def test_nrrd_in_lps_is_the_same_voxels_in_ras(tmp_path):
    """An NRRD written in LPS places every voxel where the RAS NIfTI of the same labels does."""
    data, affine = labels_array(), grid_affine(2.0, [4.0, 5.0, 6.0])
    nifti = load_volume(write_nifti(tmp_path / "a.nii", data, affine))
    lps = load_volume(write_nrrd(tmp_path / "a.nrrd", data, FLIP_XY @ affine))
    assert lps.space == "LPS" and np.array_equal(lps.data, data)
    assert np.allclose(lps.ras_affine(), nifti.ras_affine())


def test_seg_nrrd_segments_names_colours_and_layers(tmp_path):
    """A Slicer .seg.nrrd of overlapping segments (a list axis of two layers) gives each segment its name,
    label value, layer and colour, from the SegmentN_* fields."""
    layers = np.zeros((2, 6, 6, 6), dtype=np.uint8)
    layers[0, 1:5, 1:5, 1:5] = 1
    layers[1, 2:4, 2:4, 2:4] = 3  # overlaps segment 'liver' in layer 0
    extra = {"Segment0_Name": "liver", "Segment0_LabelValue": "1", "Segment0_Layer": "0",
             "Segment0_Color": "1 0 0", "Segment1_Name": "tumour", "Segment1_LabelValue": "3",
             "Segment1_Layer": "1", "Segment1_Color": "0 0.5 1"}
    volume = load_volume(write_nrrd(tmp_path / "s.seg.nrrd", layers, FLIP_XY @ grid_affine(1.0, [0, 0, 0]),
                                    extra, layered=True))
    assert volume.layer_count == 2 and volume.shape == (6, 6, 6)
    named = {label.name: label for label in volume.labels}
    assert (named["liver"].value, named["liver"].layer, named["liver"].color) == (1, 0, (255, 0, 0))
    assert (named["tumour"].value, named["tumour"].layer, named["tumour"].color) == (3, 1, (0, 128, 255))
    assert volume.label_mask(named["tumour"]).sum() == 8 and volume.label_mask(named["liver"]).sum() == 64


def test_structure_folder_is_layers_of_named_structures(tmp_path):
    """A folder of one mask per structure gives one label per file named by its stem; overlapping structures
    go to separate layers, each structure's voxels kept exactly."""
    affine = grid_affine(1.0, [0, 0, 0])
    liver = np.zeros((6, 6, 6), np.uint8)
    liver[1:5, 1:5, 1:5] = 1
    tumour = np.zeros_like(liver)
    tumour[2:4, 2:4, 2:4] = 1
    spleen = np.zeros_like(liver)
    spleen[5, 5, 5] = 1
    for name, mask in (("liver", liver), ("tumour", tumour), ("spleen", spleen)):
        write_nifti(tmp_path / f"{name}.nii.gz", mask, affine)
    volume = load_volume(tmp_path)
    named = {label.name: label for label in volume.labels}
    assert set(named) == {"liver", "tumour", "spleen"} and volume.layer_count == 2
    for name, mask in (("liver", liver), ("tumour", tumour), ("spleen", spleen)):
        assert np.array_equal(volume.label_mask(named[name]), mask.astype(bool))


def test_dicom_series_in_hounsfield_units_ordered_by_position(tmp_path):
    """A DICOM series whose file names run against the slice order reads in position order, in HU (stored
    value x slope + intercept), in LPS with the slice step from the positions."""
    rng = np.random.default_rng(3)
    hu = rng.integers(-1000, 2000, size=(5, 4, 6)).astype(np.float32)
    affine = FLIP_XY @ grid_affine(0.5, [1.0, 2.0, 3.0])
    affine[2, 2] = 2.5
    volume = load_volume(write_dicom_series(tmp_path / "ct", hu, affine, slope=1.0, intercept=-1024.0))
    assert volume.kind == "intensity" and volume.space == "LPS"
    assert np.array_equal(volume.data, hu) and np.allclose(volume.affine, affine)


def test_shared_dicom_series_reads(shared_data):
    """The shared CT series: 512 x 512 x 20 in LPS, HU from about -1024."""
    volume = load_volume(shared_data / "imaging" / "ct_dicom")
    assert volume.shape == (512, 512, 20) and volume.space == "LPS" and volume.kind == "intensity"
    assert volume.data.min() >= -1100 and np.allclose(volume.voxel_size_mm[:2], 0.9765625)


def test_shared_label_map_has_its_41_labels(shared_data):
    volume = load_volume(shared_data / "imaging" / "example_seg.nii.gz")
    assert volume.kind == "labels" and len(volume.labels) == 41
    assert int(volume.label_mask(next(l for l in volume.labels if l.value == 13)).sum()) == 1


def _raises(path, match):
    with pytest.raises(InputError, match=match) as caught:
        load_volume(path)
    assert "\n" not in str(caught.value) and caught.value.exit_code == 2


def test_gzip_bomb_refused_from_its_declared_size(tmp_path):
    """A NIfTI header declaring more bytes than MAX_VOLUME_BYTES is refused before the data are inflated."""
    import nibabel as nib

    image = nib.Nifti1Image(np.zeros((2, 2, 2), np.uint8), np.eye(4))
    side = int(round((MAX_VOLUME_BYTES * 2) ** (1 / 3)))
    image.header.set_data_shape((side, side, side))
    path = tmp_path / "bomb.nii.gz"
    with gzip.open(path, "wb") as handle:
        handle.write(image.header.binaryblock + b"\0" * 4)
        zero = b"\0" * (1 << 20)
        for _ in range(4):
            handle.write(zero)
    _raises(path, "more than the")


def test_nrrd_with_more_data_than_declared_refused(tmp_path):
    """An NRRD whose gzip inflates past its declared size is refused without inflating the rest."""
    path = write_nrrd(tmp_path / "a.nrrd", labels_array(), np.eye(4))
    text = path.read_bytes()
    head, _, _ = text.partition(b"\n\n")
    path.write_bytes(head + b"\n\n" + gzip.compress(b"\0" * (10 << 20)))
    _raises(path, "more data than its header declares")


def test_short_data_refused(tmp_path):
    path = write_nifti(tmp_path / "a.nii", labels_array(), np.eye(4))
    path.write_bytes(path.read_bytes()[:-100])
    _raises(path, "do not match its header")


def test_nan_voxels_refused(tmp_path):
    data = np.zeros((4, 4, 4), np.float32)
    data[1, 2, 3] = np.nan
    _raises(write_nifti(tmp_path / "a.nii", data, np.eye(4)), "NaN")


@pytest.mark.parametrize("affine, match", [
    (np.diag([1.0, 0.0, 1.0, 1.0]), "singular"),
    (np.array([[1.0, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "not orthogonal"),
    (np.diag([1e-5, 1e-5, 1e-5, 1.0]), "voxel size"),
    (np.diag([500.0, 1, 1, 1]), "voxel size"),
])
def test_bad_affines_refused(tmp_path, affine, match):
    """Singular, sheared, microscopic or absurd voxel axes are refused, one line each."""
    path = tmp_path / "a.nrrd"
    write_nrrd(path, labels_array(), affine)
    _raises(path, match)


def test_mixed_grids_in_a_structure_folder_refused(tmp_path):
    write_nifti(tmp_path / "a.nii.gz", labels_array(), np.eye(4))
    write_nifti(tmp_path / "b.nii.gz", labels_array(), grid_affine(2.0, [0, 0, 0]))
    _raises(tmp_path, "must share one grid")
