"""Volume readers, one per format, each through a well-kept library and each giving a checked
:class:`~heoslice.volume.model.Volume`: NIfTI (nibabel), NRRD and Slicer ``.seg.nrrd`` (pynrrd's header
parser; the data inflated here, bounded by the size the header declares), a folder of one NIfTI label
file per structure (TotalSegmentator's output) and a DICOM series folder (pydicom).

Every size is checked from the header before data is read (:func:`check_declared_size`), so a
decompression bomb is refused from what it declares, and data longer or shorter than declared is one line.
"""

from __future__ import annotations

import bz2
import hashlib

import re
import zlib
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import check_regular, open_regular
from heoslice.volume.model import (
    MAX_LABELS,
    Label,
    Volume,
    as_label_array,
    check_affine,
    check_declared_size,
    check_values,
    label_values,
    make_labels,
)

NIFTI_SUFFIXES = (".nii", ".nii.gz")
NRRD_SUFFIXES = (".nrrd", ".nhdr")
VOLUME_SUFFIXES = NIFTI_SUFFIXES + NRRD_SUFFIXES
#: Most files a folder (structures, DICOM slices) may hold.
MAX_FOLDER_FILES = 4096
#: Largest single DICOM file read, bytes.
MAX_DICOM_FILE_BYTES = 256 << 20
#: A label map has at most this many distinct values when its kind is guessed (more: an intensity volume).
GUESS_MAX_LABELS = 1000
#: Relative spread of a DICOM series' slice steps accepted as one even spacing.
SLICE_STEP_TOLERANCE = 0.01
#: Largest part of a DICOM slice step off the slice normal, relative to the step (more: gantry tilt, a shear),
#: plus POSITION_ROUNDING_MM for positions written to two decimals; checked per step and first to last slice.
SLICE_NORMAL_TOLERANCE = 1e-3
POSITION_ROUNDING_MM = 0.02
#: A guessed label map with more values than this is flagged (likely an intensity image: say --as intensity).
GUESS_WARN_LABELS = 64
#: NIfTI xyzt_units spatial code (xyzt_units % 8) -> (its name, millimetres per unit); 0 "unknown" is taken as mm.
NIFTI_UNITS = {0: ("unknown", 1.0), 1: ("meter", 1000.0), 2: ("mm", 1.0), 3: ("micron", 1e-3)}
#: NRRD "space units" / "units" entries -> millimetres per unit ("" and "???": not given, taken as mm).
NRRD_UNITS = {"": 1.0, "???": 1.0, "none": 1.0, "mm": 1.0, "millimeter": 1.0, "millimetre": 1.0,
              "millimeters": 1.0, "millimetres": 1.0, "m": 1000.0, "meter": 1000.0, "metre": 1000.0,
              "meters": 1000.0, "metres": 1000.0, "cm": 10.0, "um": 1e-3, "\u00b5m": 1e-3, "micron": 1e-3,
              "microns": 1e-3, "micrometer": 1e-3, "micrometre": 1e-3, "micrometers": 1e-3, "micrometres": 1e-3}
#: NRRD axis kinds of a list of label layers (a Slicer .seg.nrrd of overlapping segments), and of a spatial axis.
NRRD_LIST_KINDS = ("list", "none", "???")
NRRD_SPACE_KINDS = ("domain", "space")
#: The dtype kinds a volume's voxels may have: bool, signed and unsigned integers, floats.
VOXEL_KINDS = "biuf"
_READ_BLOCK = 1 << 20
_LPS = {"left-posterior-superior": "LPS", "LPS": "LPS", "right-anterior-superior": "RAS", "RAS": "RAS"}


def is_volume_path(path: Path) -> bool:
    """Whether ``path`` names a volume (a NIfTI or NRRD file, or a folder) rather than a mesh file."""
    name = str(path).lower()
    return Path(path).is_dir() or name.endswith(VOLUME_SUFFIXES)


def load_volume(path: Path, kind: str | None = None) -> Volume:
    """The volume at ``path``: a NIfTI or NRRD file, a folder of per-structure NIfTI label files or a DICOM
    series folder. ``kind`` forces "labels" or "intensity"; None guesses (:func:`guess_kind`); a DICOM series
    is an intensity volume. One-line InputError naming the file for anything unreadable."""
    path = Path(path)
    if path.is_dir():
        return _read_folder(path, kind)
    check_regular(path, "volume")
    name = path.name.lower()
    if name.endswith(NIFTI_SUFFIXES):
        return read_nifti(path, kind)
    if name.endswith(NRRD_SUFFIXES):
        return read_nrrd(path, kind)
    raise InputError(f"{path}: not a volume file (NIfTI .nii/.nii.gz, NRRD .nrrd, or a folder)")


def guess_kind(data: np.ndarray) -> str:
    """"labels" for integer voxels, none negative, with at most GUESS_MAX_LABELS distinct values; else
    "intensity" (a CT's air is negative)."""
    if data.dtype.kind == "b":
        return "labels"
    if data.dtype.kind not in "iu" or (data.size and data.min() < 0):
        return "intensity"
    return "labels" if len(label_values(data)) <= GUESS_MAX_LABELS else "intensity"


def _finish(path: Path, data: np.ndarray, affine: np.ndarray, space: str, kind: str | None,
            known: dict[int, Label] | None, sha256: str, warnings: tuple[str, ...] = ()) -> Volume:
    """The checked Volume of one layer of ``data``."""
    affine = check_affine(path, affine, data.shape[-3:])
    guessed = kind is None
    kind = kind or guess_kind(data)
    if kind == "labels":
        data = as_label_array(path, data)
        labels = make_labels(path, data, known)
        if guessed and len(labels) > GUESS_WARN_LABELS:
            warnings = (*warnings, f"read as a label map of {len(labels)} values (guessed from its whole-number "
                                   "voxels); if it is an intensity image (a CT), say --as intensity")
        return Volume(data, affine, space, "labels", labels, path, sha256, warnings, kind_guessed=guessed)
    check_values(path, data)
    return Volume(data, affine, space, "intensity", (), path, sha256, warnings, kind_guessed=guessed)


def file_digest(path: Path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    digest = hashlib.sha256()
    with open_regular(path, "volume") as handle:
        for block in iter(lambda: handle.read(_READ_BLOCK), b""):
            digest.update(block)
    return digest.hexdigest()


def _spatial(path: Path, data_shape: tuple[int, ...]) -> tuple[int, ...]:
    """The shape of a volume, 3 axes; trailing axes of length 1 dropped, fewer than 3 refused."""
    shape = list(data_shape)
    while len(shape) > 3 and shape[-1] == 1:
        shape.pop()
    if len(shape) != 3:
        raise InputError(f"{path}: a {len(data_shape)}-D image of shape {tuple(data_shape)}; "
                         "heoslice reads 3-D volumes")
    return tuple(shape)


# --- NIfTI -------------------------------------------------------------------------------------------------

def _nifti_image(path: Path):
    import nibabel as nib  # loaded by volume commands only

    try:
        return nib.load(str(path))
    except Exception as err:  # nibabel raises ImageFileError, ValueError, OSError, EOFError for bad files
        raise InputError(f"{path}: not a readable NIfTI file ({' '.join(str(err).split())[:160]})") from None


def read_nifti(path: Path, kind: str | None = None) -> Volume:
    """A NIfTI-1/2 volume (.nii, .nii.gz) in RAS: the sform/qform affine nibabel chooses; scaled intensities
    (scl_slope, scl_inter) for an intensity volume, raw values for a label map."""
    image = _nifti_image(path)
    header = image.header
    check_voxel_dtype(path, header.get_data_dtype())
    shape = _spatial(path, image.shape)
    check_declared_size(path, shape, header.get_data_dtype().itemsize)
    try:
        raw = np.asanyarray(image.dataobj.get_unscaled()).reshape(shape)
        slope, inter = image.dataobj.slope, image.dataobj.inter
    except Exception as err:  # short data, truncated gzip
        raise InputError(f"{path}: its data do not match its header ({' '.join(str(err).split())[:160]})") from None
    scaled = (slope, inter) != (1.0, 0.0) and np.isfinite(slope) and slope != 0
    data = raw * np.float32(slope) + np.float32(inter) if scaled and kind != "labels" else raw
    code = int(header["xyzt_units"]) % 8
    if code not in NIFTI_UNITS:
        raise InputError(f"{path}: NIfTI spatial unit code {code} is not a known unit "
                         f"({', '.join(name for name, _ in NIFTI_UNITS.values())})")
    affine = np.diag([NIFTI_UNITS[code][1]] * 3 + [1.0]) @ image.affine
    warnings = ()
    if int(header["sform_code"]) == 0 and int(header["qform_code"]) == 0:
        warnings = ("no orientation in the header (sform and qform codes 0): left/right cannot be trusted",)
    return _finish(path, data, affine, "RAS", kind, None, file_digest(path), warnings)


def check_voxel_dtype(path: Path, dtype: np.dtype) -> None:
    """Refuse voxels that are not one number each (RGB or other structured, complex, text): one line."""
    if dtype.kind not in VOXEL_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise InputError(f"{path}: voxels of type {dtype} are not read (heoslice reads one bool, integer or float "
                         "per voxel: a label map or a grey-value scan)")


# --- NRRD --------------------------------------------------------------------------------------------------

def _segment_labels(path: Path, header: dict, layered: bool) -> dict[tuple[int, int], Label]:
    """{(layer, value): Label} of a Slicer .seg.nrrd's SegmentN_* fields (name, label value, layer, colour:
    three numbers 0..1); InputError naming the file and the field for a malformed one."""
    numbers = sorted({int(m.group(1)) for key in header if (m := re.match(r"^Segment(\d+)_", key))})
    labels = {}
    for number in numbers:
        field = lambda name, default=None: header.get(f"Segment{number}_{name}", default)  # noqa: E731
        value, layer = (_segment_number(path, number, name, field(name, default))
                        for name, default in (("LabelValue", 1), ("Layer", number if layered else 0)))
        color = field("Color")
        rgb = None if color is None else _segment_colour(path, number, str(color))
        labels[(layer, value)] = Label(value, str(field("Name", f"Segment{number}")), rgb, layer)
    return labels


def _segment_number(path: Path, number: int, name: str, text) -> int:
    """The whole number of a SegmentN_LabelValue or SegmentN_Layer field."""
    try:
        return int(str(text).strip())
    except ValueError:
        raise InputError(f"{path}: Segment{number}_{name} {str(text)!r} is not a whole number") from None


def _segment_colour(path: Path, number: int, text: str) -> tuple[int, int, int]:
    """(r, g, b) 0..255 of a SegmentN_Color field: three numbers 0..1."""
    try:
        values = [float(c) for c in text.split()]
    except ValueError:
        values = []
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise InputError(f"{path}: Segment{number}_Color {text!r} is not three numbers from 0 to 1")
    return tuple(int(round(255 * v)) for v in values)


def _nrrd_units(path: Path, header: dict, field: str, count: int) -> np.ndarray:
    """(count,) float: millimetres per unit of each entry of an NRRD units field (1 where none is given)."""
    units = header.get(field)
    if units is None:
        return np.ones(count)
    units = [str(unit).strip().lower() for unit in units]
    unknown = [unit for unit in units if unit not in NRRD_UNITS]
    if unknown:
        raise InputError(f"{path}: NRRD {field} {unknown[0]!r} is not a known length unit (m, cm, mm, micron)")
    if len(units) != count:
        raise InputError(f"{path}: NRRD {field} gives {len(units)} units for {count} axes")
    return np.array([NRRD_UNITS[unit] for unit in units])


def _nrrd_axes(path: Path, header: dict, ndim: int) -> tuple[list[int], list[int]]:
    """(the spatial axes, the other axes) of an NRRD's data, from its space directions (a "none" row is not
    spatial) or, without them, its kinds (domain, space) where they say anything ("???" and "none" do not) or
    spacings (NaN: not spatial); else the first three."""
    def says(name: str) -> bool:
        value = header.get(name)
        return value is not None and (name != "kinds" or any(str(kind).lower() not in ("???", "none")
                                                              for kind in value))

    field = next((name for name in ("space directions", "kinds", "spacings") if says(name)), None)
    if field == "space directions":
        spatial = [row is not None and not np.all(np.isnan(np.asarray(row, float))) for row in header[field]]
    elif field == "kinds":
        spatial = [str(kind).lower() in NRRD_SPACE_KINDS for kind in header[field]]
    elif field == "spacings":
        spatial = [bool(np.isfinite(float(spacing))) for spacing in header[field]]
    else:
        spatial = [axis < 3 for axis in range(ndim)]
    if len(spatial) != ndim:
        raise InputError(f"{path}: NRRD {field} describe {len(spatial)} axes of a {ndim}-D image")
    return [a for a in range(ndim) if spatial[a]], [a for a in range(ndim) if not spatial[a]]


def _nrrd_layout(path: Path, header: dict, data: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """``data`` as (i, j, k) or (layers, i, j, k) and its three spatial axes (in the file's axis order): the
    list axis of layered label maps moved first, other axes of length 1 dropped; any other 4-D image (a time
    series, RGB vectors) refused."""
    spatial, others = _nrrd_axes(path, header, data.ndim)
    if len(spatial) != 3:
        raise InputError(f"{path}: a {data.ndim}-D NRRD with {len(spatial)} spatial axes (shape {data.shape}); "
                         "heoslice reads 3-D volumes")
    kinds = header.get("kinds") or ["???"] * data.ndim
    others = [axis for axis in others if data.shape[axis] > 1]
    if not others:
        return data.transpose(spatial + [a for a in range(data.ndim) if a not in spatial]).reshape(
            [data.shape[a] for a in spatial]), spatial
    kind = str(kinds[others[0]]).lower()
    if len(others) > 1 or kind not in NRRD_LIST_KINDS:
        raise InputError(f"{path}: a {data.ndim}-D NRRD (shape {data.shape}, kinds {' '.join(map(str, kinds))}) "
                         "is not a 3-D volume or a label map in layers (a list axis); heoslice does not read "
                         "time series or vector (RGB) images")
    rest = [a for a in range(data.ndim) if a not in spatial and a != others[0]]
    moved = data.transpose([others[0]] + spatial + rest)
    return moved.reshape(moved.shape[:4]), spatial


def _inflate(path: Path, handle, encoding: str, expected: int) -> bytes:
    """The ``expected`` data bytes after the header, inflated (gzip, bzip2) or raw, reading no more than
    ``expected`` + 1 bytes of output: more data than declared, or less, is refused."""
    if encoding == "raw":
        data = handle.read(expected + 1)
    else:
        inflater = zlib.decompressobj(zlib.MAX_WBITS | 16) if encoding in ("gzip", "gz") else bz2.BZ2Decompressor()
        pieces, total = [], 0
        while total <= expected:
            block = handle.read(_READ_BLOCK)
            if not block:
                break
            try:
                if isinstance(inflater, bz2.BZ2Decompressor):
                    piece = inflater.decompress(block, max_length=expected + 1 - total)
                else:
                    piece = inflater.decompress(block, expected + 1 - total)
            except (OSError, zlib.error, EOFError) as err:
                raise InputError(f"{path}: corrupt {encoding} data ({err})") from None
            pieces.append(piece)
            total += len(piece)
        data = b"".join(pieces)
    if len(data) > expected:
        raise InputError(f"{path}: more data than its header declares ({expected} bytes): refused")
    if len(data) < expected:
        raise InputError(f"{path}: {len(data)} bytes of data, but its header declares {expected}")
    return data


def read_nrrd(path: Path, kind: str | None = None) -> Volume:
    """An NRRD volume (raw, gzip or bzip2 encoded) in its ``space`` (LPS unless it says RAS), with a Slicer
    .seg.nrrd's segment names, label values, layers and colours; a 4-D file with a list axis first is a
    label map of several layers (overlapping segments)."""
    import nrrd  # loaded by volume commands only

    with open_regular(path, "volume") as handle:
        try:
            header = nrrd.read_header(handle)
            dtype = nrrd.reader._determine_datatype(header)
        except Exception as err:  # nrrd.NRRDError, ValueError for malformed fields
            raise InputError(f"{path}: not a readable NRRD header ({' '.join(str(err).split())[:160]})") from None
        if "data file" in header or "datafile" in header:
            raise InputError(f"{path}: detached NRRD data (data file) is not read; save it as one .nrrd")
        if int(header.get("byte skip", 0)) or int(header.get("line skip", 0)):
            raise InputError(f"{path}: NRRD byte or line skip is not supported")
        sizes = [int(n) for n in header["sizes"]]
        check_declared_size(path, sizes, dtype.itemsize)
        encoding = str(header["encoding"]).lower()
        if encoding not in ("raw", "gzip", "gz", "bzip2", "bz2"):
            raise InputError(f"{path}: NRRD encoding {encoding!r} is not read (raw, gzip and bzip2 are)")
        raw = _inflate(path, handle, encoding, int(np.prod(sizes)) * dtype.itemsize)
    data = np.frombuffer(raw, dtype=dtype).reshape(sizes[::-1]).T  # NRRD's first axis varies fastest
    data, spatial = _nrrd_layout(path, header, data)
    layered = data.ndim == 4
    if layered and kind == "intensity":
        raise InputError(f"{path}: a label map in {data.shape[0]} layers (overlapping segments); it cannot be "
                         "read --as intensity")
    directions = header.get("space directions")
    if directions is None:
        spacings = np.asarray(header.get("spacings", [1.0] * len(sizes)), dtype=np.float64)
        if len(spacings) != len(sizes) or not np.all(np.isfinite(spacings[spatial])):
            raise InputError(f"{path}: NRRD spacings do not give a spacing for each of the three voxel axes")
        axes = np.diag(spacings[spatial] * _nrrd_units(path, header, "units", len(sizes))[spatial])
    else:
        axes = np.asarray([directions[a] for a in spatial], dtype=np.float64).T
    if axes.shape != (3, 3):
        raise InputError(f"{path}: NRRD space directions do not give three 3-D voxel axes")
    affine = np.eye(4)
    affine[:3, :3] = axes
    affine[:3, 3] = np.asarray(header.get("space origin", [0.0, 0.0, 0.0]), dtype=np.float64)
    affine = np.diag([*_nrrd_units(path, header, "space units", 3), 1.0]) @ affine
    space = _LPS.get(str(header.get("space", "left-posterior-superior")))
    if space is None:
        raise InputError(f"{path}: NRRD space {header.get('space')!r} is not a patient space (LPS or RAS)")
    segments = _segment_labels(path, header, layered)
    sha = file_digest(path)
    if not layered:
        known = {value: label for (layer, value), label in segments.items() if layer == 0}
        volume = _finish(path, data, affine, space, kind if kind or not segments else "labels", known, sha)
        extra = tuple(label for label in known.values() if label not in volume.labels)
        return volume if not extra else _with_labels(volume, volume.labels + extra)
    data = as_label_array(path, np.ascontiguousarray(data))
    affine = check_affine(path, affine, data.shape[1:])
    labels = dict(segments)
    for layer in range(data.shape[0]):
        for value in label_values(data[layer]):
            labels.setdefault((layer, int(value)), Label(int(value), None, None, layer))
    if len(labels) > MAX_LABELS:
        raise InputError(f"{path}: {len(labels)} labels, more than the {MAX_LABELS} heoslice reads")
    return Volume(data, affine, space, "labels", tuple(labels[key] for key in sorted(labels)), path, sha)


def _with_labels(volume: Volume, labels: tuple[Label, ...]) -> Volume:
    from dataclasses import replace

    return replace(volume, labels=tuple(sorted(labels, key=lambda label: (label.layer, label.value))))


# --- folders: one NIfTI per structure, or a DICOM series -----------------------------------------------------

def _folder_files(path: Path) -> list[Path]:
    try:
        files = sorted(entry for entry in path.iterdir() if entry.is_file() and not entry.name.startswith("."))
    except OSError as err:
        raise InputError(f"{path}: cannot list the folder ({err.strerror})") from None
    if len(files) > MAX_FOLDER_FILES:
        raise InputError(f"{path}: {len(files)} files, more than the {MAX_FOLDER_FILES} heoslice reads from a folder")
    if not files:
        raise InputError(f"{path}: an empty folder (expected NIfTI label files or a DICOM series)")
    return files


def _read_folder(path: Path, kind: str | None) -> Volume:
    files = _folder_files(path)
    niftis = [file for file in files if file.name.lower().endswith(NIFTI_SUFFIXES)]
    if niftis:
        if kind == "intensity":
            raise InputError(f"{path}: a folder of NIfTI files is read as one label file per structure")
        return read_structure_folder(path, niftis)
    volume = read_dicom_series(path, files)
    return volume if kind != "labels" else _finish(path, volume.data, volume.affine, "LPS", "labels", None,
                                                   volume.sha256)


def _structure_name(file: Path) -> str:
    name = file.name
    for suffix in (".nii.gz", ".nii"):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return file.stem


def read_structure_folder(path: Path, files: list[Path]) -> Volume:
    """A label map of several layers from one NIfTI mask per structure (non-zero voxels are the structure,
    the file's stem its name), all on one grid. Structures that do not overlap share a layer (each its own
    value, 1.. in file order); one that overlaps every layer so far starts a new layer."""
    layers: list[np.ndarray] = []
    labels, affine, digest, shape, warnings = [], None, hashlib.sha256(), None, {}
    for number, file in enumerate(files, start=1):
        volume = read_nifti(file, "labels")
        if affine is None:
            affine, shape = volume.affine, volume.shape
        elif volume.shape != shape or not np.allclose(volume.affine, affine, atol=1e-4):
            raise InputError(f"{file}: its grid (shape {volume.shape}, affine) differs from {files[0].name}'s; "
                             "the structures of a folder must share one grid")
        digest.update(f"{file.name}\0{volume.sha256}\n".encode())
        warnings.update(dict.fromkeys(f"{file.name}: {text}" for text in volume.warnings))
        mask = volume.data != 0
        layer = next((index for index, existing in enumerate(layers) if not np.any(existing[mask])), None)
        if layer is None:
            if len(layers) >= 255:
                raise InputError(f"{path}: structures overlap more than 255 deep")
            layers.append(np.zeros(shape, dtype=np.uint16))
            layer = len(layers) - 1
        layers[layer][mask] = number
        labels.append(Label(number, _structure_name(file), None, layer))
    data = layers[0] if len(layers) == 1 else np.stack(layers)
    return Volume(data, affine, "RAS", "labels", tuple(labels), path, digest.hexdigest(), tuple(warnings),
                  names_only=True)


def read_dicom_series(path: Path, files: list[Path]) -> Volume:
    """One DICOM series (a folder of single-slice files) as an intensity volume in LPS: stored values times
    RescaleSlope plus RescaleIntercept (Hounsfield units for a CT), slices ordered by ImagePositionPatient
    along the slice normal (never by file name), their spacing from those positions."""
    import pydicom  # loaded by volume commands only

    slices, series = [], set()
    digest = hashlib.sha256()
    for file in files:
        size = check_regular(file, "DICOM").st_size
        if size > MAX_DICOM_FILE_BYTES:
            raise InputError(f"{file}: DICOM file of {size} bytes is larger than the {MAX_DICOM_FILE_BYTES}-byte limit")
        try:
            with open_regular(file, "DICOM") as handle:
                dataset = pydicom.dcmread(handle, force=False)
        except Exception as err:  # pydicom.errors.InvalidDicomError and friends
            raise InputError(f"{file}: not a DICOM file ({' '.join(str(err).split())[:120]})") from None
        if "PixelData" not in dataset:
            continue
        for keyword in ("ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing", "Rows", "Columns"):
            if keyword not in dataset:
                raise InputError(f"{file}: DICOM slice without {keyword}: not a volume slice")
        if int(dataset.get("SamplesPerPixel", 1) or 1) != 1:
            raise InputError(f"{file}: a DICOM slice of {int(dataset.SamplesPerPixel)} samples per pixel (colour); "
                             "heoslice reads grey-value series")
        series.add(str(dataset.get("SeriesInstanceUID", "")))
        slices.append((file, dataset))
        digest.update(file_digest(file).encode())
    if not slices:
        raise InputError(f"{path}: no DICOM image slices (and no NIfTI files) in the folder")
    if len(series) > 1:
        raise InputError(f"{path}: holds {len(series)} DICOM series; give a folder of one series")
    first = slices[0][1]
    orientation = np.asarray(first.ImageOrientationPatient, dtype=np.float64)
    row, column = orientation[:3], orientation[3:]
    normal = np.cross(row, column)
    rows, columns = int(first.Rows), int(first.Columns)
    check_declared_size(path, (columns, rows, len(slices)), 4)
    corners = []
    for file, dataset in slices:
        if not np.allclose(np.asarray(dataset.ImageOrientationPatient, float), orientation, atol=1e-4) or (
                int(dataset.Rows), int(dataset.Columns)) != (rows, columns):
            raise InputError(f"{file}: its orientation or size differs from the series' first slice")
        corners.append(np.asarray(dataset.ImagePositionPatient, float))
    positions = np.asarray(corners) @ normal
    order = np.argsort(positions, kind="stable")
    along = positions[order]
    steps = np.diff(along)
    if len(steps) and (np.any(steps <= 0) or np.ptp(steps) > SLICE_STEP_TOLERANCE * np.mean(steps)):
        raise InputError(f"{path}: slice positions are not evenly spaced along the slice normal "
                         f"(steps {np.round(steps.min(), 4)} .. {np.round(steps.max(), 4)} mm; duplicated or "
                         "missing slices)")
    check_slice_normal(path, np.asarray(corners)[order], normal)
    step = float(np.mean(steps)) if len(steps) else float(first.get("SliceThickness", 1.0) or 1.0)
    volume = np.empty((columns, rows, len(slices)), dtype=np.float32)
    for k, index in enumerate(order):
        file, dataset = slices[index]
        try:
            pixels = dataset.pixel_array
        except Exception as err:  # missing decoder, truncated pixel data
            raise InputError(f"{file}: cannot decode its pixel data ({' '.join(str(err).split())[:120]})") from None
        slope = float(dataset.get("RescaleSlope", 1.0) or 1.0)
        intercept = float(dataset.get("RescaleIntercept", 0.0) or 0.0)
        volume[:, :, k] = (pixels.astype(np.float32) * np.float32(slope) + np.float32(intercept)).T
    spacing = [float(value) for value in first.PixelSpacing]  # (between rows, between columns)
    affine = np.eye(4)
    affine[:3, 0] = row * spacing[1]
    affine[:3, 1] = column * spacing[0]
    affine[:3, 2] = normal * step
    affine[:3, 3] = np.asarray(slices[order[0]][1].ImagePositionPatient, dtype=np.float64)
    affine = check_affine(path, affine, volume.shape)
    check_values(path, volume)
    return Volume(volume, affine, "LPS", "intensity", (), path, digest.hexdigest())


def check_slice_normal(path: Path, corners: np.ndarray, normal: np.ndarray) -> None:
    """Refuse a series whose slice corners ((n, 3) mm, ImagePositionPatient in slice order) do not step along
    the slice normal, from one slice to the next or from the first to the last (a small tilt adds up): a
    gantry-tilted (sheared) grid, whose slices the normal alone would misplace."""
    moves = np.concatenate([np.diff(corners, axis=0), corners[-1:] - corners[:1]])
    along = moves @ normal
    off = np.linalg.norm(moves - along[:, None] * normal, axis=1)
    excess = off - SLICE_NORMAL_TOLERANCE * np.abs(along) - POSITION_ROUNDING_MM
    if len(corners) > 1 and np.any(excess > 0):
        worst = int(np.argmax(excess))
        raise InputError(f"{path}: the slices step {off[worst]:.3g} mm sideways per {abs(along[worst]):.3g} mm "
                         "along the slice normal (gantry tilt: a sheared volume); resample it to an orthogonal "
                         "grid")
