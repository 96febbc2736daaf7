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


@pytest.mark.parametrize("unit, mm", [("meter", 1000.0), ("micron", 1e-3), ("mm", 1.0), ("unknown", 1.0)])
def test_nifti_spatial_units_scale_to_millimetres(tmp_path, unit, mm):
    """A NIfTI's xyzt_units spatial unit scales its affine (voxel axes and origin) to mm: a micro-CT in microns
    is not 1000 times too large; 'unknown' keeps the mm assumption."""
    import nibabel as nib

    affine = grid_affine(2.0 / mm, np.array([10.0, -20.0, 30.0]) / mm)  # 2 mm voxels, in the file's unit
    image = nib.Nifti1Image(labels_array(), affine)
    image.header.set_xyzt_units(unit)
    path = tmp_path / "u.nii.gz"
    nib.save(image, str(path))
    volume = load_volume(path)
    assert np.allclose(volume.affine, grid_affine(2.0, [10.0, -20.0, 30.0]))


def test_nifti_unknown_unit_code_refused(tmp_path):
    """A spatial unit code NIfTI does not define (here 5) is refused, naming the file."""
    import nibabel as nib

    image = nib.Nifti1Image(labels_array(), np.eye(4))
    image.header["xyzt_units"] = 5
    path = tmp_path / "u.nii"
    nib.save(image, str(path))
    _raises(path, "u.nii: NIfTI spatial unit code 5")


@pytest.mark.parametrize("units, mm", [(["m", "m", "m"], 1000.0), (["um", "um", "um"], 1e-3),
                                       (["mm", "mm", "mm"], 1.0), (["cm", "cm", "cm"], 10.0)])
def test_nrrd_space_units_scale_to_millimetres(tmp_path, units, mm):
    """An NRRD's 'space units' scale its space directions and origin to mm."""
    affine = grid_affine(0.5 / mm, np.array([1.0, 2.0, 3.0]) / mm)  # 0.5 mm voxels, in the file's unit
    volume = load_volume(write_nrrd(tmp_path / "u.nrrd", labels_array(), affine, {"space units": units}))
    assert np.allclose(volume.affine, grid_affine(0.5, [1.0, 2.0, 3.0]))


def test_nrrd_unknown_space_unit_refused(tmp_path):
    path = write_nrrd(tmp_path / "u.nrrd", labels_array(), np.eye(4), {"space units": ["mm", "furlong", "mm"]})
    _raises(path, "u.nrrd: NRRD space units 'furlong' is not a known length unit")


def _nrrd_with_axes(path, data, kinds, directions, origin=(0.0, 0.0, 0.0), extra=None):
    import nrrd

    header = {"space": "left-posterior-superior", "space origin": list(origin), "encoding": "gzip",
              "kinds": kinds, "space directions": np.array(directions, dtype=float)}
    header.update(extra or {})
    nrrd.write(str(path), data, header, custom_field_map={key: "string" for key in extra or {}})
    return path


NONE3 = [np.nan] * 3
AXES = [[2.0, 0, 0], [0, 1.5, 0], [0, 0, 2.5]]


@pytest.mark.parametrize("list_axis", [0, 1, 3])
def test_4d_nrrd_list_axis_found_wherever_it_is(tmp_path, list_axis):
    """A label map in layers reads the same, voxel for voxel, whichever axis holds the list of layers (found
    from kinds and the 'none' space direction, not assumed first)."""
    layers = np.zeros((2, 6, 5, 4), np.uint8)
    layers[0, 1:4, 1:3, 1:3] = 1
    layers[1, 2:5, 2:4, 0:2] = 3
    data = np.moveaxis(layers, 0, list_axis)
    kinds = ["domain"] * 3
    kinds.insert(list_axis, "list")
    directions = list(AXES)
    directions.insert(list_axis, NONE3)
    volume = load_volume(_nrrd_with_axes(tmp_path / "l.seg.nrrd", data, kinds, directions))
    assert volume.layer_count == 2 and volume.shape == (6, 5, 4)
    assert np.array_equal(volume.data, layers)
    assert np.allclose(volume.affine[:3, :3], np.array(AXES).T)


def test_4d_nrrd_singleton_list_axis_is_a_3d_label_map(tmp_path):
    """A trailing list axis of length 1 is dropped: the 3-D label map reads with its own values and axes."""
    data = labels_array()
    volume = load_volume(_nrrd_with_axes(tmp_path / "t.nrrd", data[..., None], ["domain"] * 3 + ["list"],
                                         AXES + [NONE3]))
    assert volume.layer_count == 1 and np.array_equal(volume.data, data)
    assert np.allclose(volume.affine[:3, :3], np.array(AXES).T)


@pytest.mark.parametrize("kind", ["time", "RGB-color", "vector"])
def test_4d_nrrd_time_series_or_vectors_refused(tmp_path, kind):
    """A 4-D NRRD whose extra axis is not a list of layers is refused, one line naming the file."""
    data = np.zeros((3, 6, 5, 4), np.uint8)
    path = _nrrd_with_axes(tmp_path / "v.nrrd", data, [kind] + ["domain"] * 3, [NONE3] + AXES)
    _raises(path, "v.nrrd: a 4-D NRRD .* time series or vector")


def test_4d_nrrd_label_layers_refuse_as_intensity(tmp_path):
    """--as intensity on a label map in layers is refused, not ignored."""
    layers = np.zeros((2, 6, 5, 4), np.uint8)
    path = _nrrd_with_axes(tmp_path / "l.seg.nrrd", layers, ["list"] + ["domain"] * 3, [NONE3] + AXES)
    with pytest.raises(InputError, match="l.seg.nrrd: a label map in 2 layers .* --as intensity"):
        load_volume(path, "intensity")


def test_dicom_gantry_tilt_refused(tmp_path):
    """A series whose slice corners step sideways as well as along the slice normal (gantry tilt) is refused
    with the resample advice of a sheared grid, not placed sheared."""
    hu = np.zeros((5, 4, 6), np.float32)
    affine = FLIP_XY @ grid_affine(0.5, [1.0, 2.0, 3.0])
    affine[:3, 2] = [0.0, 1.0, 2.0]  # 1 mm sideways (y) per 2 mm slice step: about 26.6 degrees of tilt
    _raises(write_dicom_series(tmp_path / "ct", hu, affine), "ct: the slices step [0-9.]+ mm sideways .*gantry tilt.*"
            "resample it to an orthogonal grid")


def test_dicom_one_slice_shifted_sideways_refused(tmp_path):
    """Each consecutive step is checked, not only first to last: one slice moved 0.5 mm sideways is refused."""
    hu = np.zeros((5, 4, 6), np.float32)
    folder = write_dicom_series(tmp_path / "ct", hu, FLIP_XY @ grid_affine(1.0, [0, 0, 0]))
    import pydicom

    path = folder / "slice_002.dcm"
    dataset = pydicom.dcmread(path)
    dataset.ImagePositionPatient = [float(dataset.ImagePositionPatient[0]) + 0.5,
                                    *map(float, dataset.ImagePositionPatient[1:])]
    dataset.save_as(path)
    _raises(folder, "sideways")


@pytest.mark.parametrize("dtype", [np.int16, np.float32])
def test_negative_label_values_refused(tmp_path, dtype):
    """A label map forced with --as labels that holds a negative value is refused, naming the file (no label
    box lookup on a negative index)."""
    data = labels_array().astype(dtype)
    data[0, 0, 0] = -1
    path = write_nifti(tmp_path / "neg.nii.gz", data, np.eye(4))
    with pytest.raises(InputError, match="neg.nii.gz: 1 voxel.* negative value"):
        load_volume(path, "labels")


def test_nifti_without_sform_or_qform_warns(tmp_path):
    """A NIfTI with both sform and qform codes 0 reads with a warning that left/right cannot be trusted; one
    with an sform does not."""
    import nibabel as nib

    image = nib.Nifti1Image(labels_array(), None)
    path = tmp_path / "bare.nii"
    nib.save(image, str(path))
    volume = load_volume(path)
    assert any("no orientation in the header" in text and "left/right" in text for text in volume.warnings)
    assert load_volume(write_nifti(tmp_path / "ok.nii", labels_array(), np.eye(4))).warnings == ()


def test_rgb_nifti_refused(tmp_path):
    """An RGB NIfTI (a structured voxel type) is one line naming the file."""
    import nibabel as nib

    rgb = np.zeros((4, 4, 4), dtype=[("R", "u1"), ("G", "u1"), ("B", "u1")])
    path = tmp_path / "rgb.nii.gz"
    nib.save(nib.Nifti1Image(rgb, np.eye(4)), str(path))
    _raises(path, "rgb.nii.gz: voxels of type .* are not read")


@pytest.mark.parametrize("field, text, match", [
    ("Segment0_LabelValue", "three", "Segment0_LabelValue 'three' is not a whole number"),
    ("Segment0_Layer", "x", "Segment0_Layer 'x' is not a whole number"),
    ("Segment0_Color", "2.0 0 0", "Segment0_Color '2.0 0 0' is not three numbers from 0 to 1"),
    ("Segment0_Color", "0.5 0.5", "Segment0_Color '0.5 0.5' is not three numbers from 0 to 1"),
])
def test_malformed_segment_fields_name_the_file(tmp_path, field, text, match):
    """A malformed SegmentN_* field is one line naming the file and the field; a colour must be three numbers
    0..1 (2.0 would be colour 510)."""
    extra = {"Segment0_Name": "liver", "Segment0_LabelValue": "5", "Segment0_Layer": "0", "Segment0_Color": "1 0 0"}
    extra[field] = text
    path = write_nrrd(tmp_path / "bad.seg.nrrd", labels_array(), np.eye(4), extra)
    _raises(path, "bad.seg.nrrd: " + match)


def test_guessed_label_map_of_many_values_warns(tmp_path):
    """An 8-bit image of more than GUESS_WARN_LABELS values, its kind guessed, reads as labels with a warning
    to say --as intensity; forced with --as labels, or with few values, it does not warn."""
    from heoslice.volume.readers import GUESS_WARN_LABELS

    data = np.arange(4 * 5 * 6, dtype=np.uint8).reshape(4, 5, 6)
    assert len(np.unique(data)) - 1 > GUESS_WARN_LABELS
    path = write_nifti(tmp_path / "ct8.nii.gz", data, np.eye(4))
    volume = load_volume(path)
    assert volume.kind_guessed and any("--as intensity" in text for text in volume.warnings)
    assert not load_volume(path, "labels").warnings and not load_volume(path, "labels").kind_guessed
    assert not load_volume(write_nifti(tmp_path / "few.nii", labels_array(), np.eye(4))).warnings


def test_dicom_small_tilt_adding_up_refused_and_rounded_positions_read(tmp_path):
    """A tilt too small to see from one slice to the next (0.01 mm per 1 mm step) is refused from the first to
    the last slice of a long series; an oblique series (no tilt) whose positions are rounded to two decimals, and
    so step sideways by up to 0.01 mm, reads."""
    import pydicom

    hu = np.zeros((3, 3, 40), np.float32)
    affine = FLIP_XY @ grid_affine(1.0, [0.0, 0.0, 0.0])
    affine[:3, 2] = [0.0, 0.01, 1.0]
    _raises(write_dicom_series(tmp_path / "tilt", hu, affine), "sideways")
    angle = np.radians(30.0)
    oblique = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]])
    affine = FLIP_XY @ grid_affine(1.0, [0.123456, 0.654321, 0.0])
    affine[:3, :3] = affine[:3, :3] @ oblique @ np.diag([1.0, 1.0, 1.2345])
    folder = write_dicom_series(tmp_path / "rounded", hu, affine)
    for path in folder.iterdir():
        dataset = pydicom.dcmread(path)
        dataset.ImagePositionPatient = [round(float(v), 2) for v in dataset.ImagePositionPatient]
        dataset.save_as(path)
    assert load_volume(folder).shape == (3, 3, 40)


def test_nrrd_spacings_with_units_scale_to_millimetres(tmp_path):
    """An NRRD without space directions takes its voxel size from spacings times its per-axis 'units'."""
    import nrrd

    path = tmp_path / "s.nrrd"
    nrrd.write(str(path), labels_array(), {"spacings": [500.0, 250.0, 1000.0], "units": ["um", "um", "um"],
                                           "encoding": "raw"})
    assert np.allclose(load_volume(path).voxel_size_mm, [0.5, 0.25, 1.0])


@pytest.mark.parametrize("header, spacing", [({"kinds": ["???"] * 3, "spacings": [1.0, 1.0, 2.0]}, (1, 1, 2)),
                                             ({"kinds": ["none"] * 3}, (1, 1, 1)),
                                             ({"spacings": [0.5, 0.5, 1.0]}, (0.5, 0.5, 1))])
def test_a_3d_nrrd_whose_kinds_say_nothing_reads_as_3d(tmp_path, header, spacing):
    """Kinds '???' or 'none' (legal, and what some writers put) say nothing of which axes are spatial: a 3-D NRRD
    with them reads as its three axes (spacings where given), as before kinds were consulted."""
    import nrrd

    data = labels_array()
    nrrd.write(str(tmp_path / "k.nrrd"), data, header)
    volume = load_volume(tmp_path / "k.nrrd")
    assert np.array_equal(volume.data, data)
    assert np.allclose(np.abs(np.diag(volume.affine)[:3]), spacing)
