"""Test-only phantoms and writers for volumes: analytic shapes voxelised on grids with off-grid centres, and
files written from arrays through nibabel, pynrrd and pydicom (the readers' independent counterparts)."""

from __future__ import annotations

import datetime
from pathlib import Path

import nibabel as nib
import nrrd
import numpy as np

#: RAS <-> LPS: x and y negated.
FLIP_XY = np.diag([-1.0, -1.0, 1.0, 1.0])
#: The torus phantom's radii (major, minor), mm: its tube at least three 3 mm voxels in radius.
TORUS = (24.0, 12.0)


def grid_affine(voxel_mm: float, origin_mm) -> np.ndarray:
    """An axis-aligned RAS affine of cubic voxels."""
    affine = np.diag([voxel_mm, voxel_mm, voxel_mm, 1.0])
    affine[:3, 3] = origin_mm
    return affine


def voxel_centres(shape, affine: np.ndarray) -> np.ndarray:
    """(i, j, k, 3) float, mm: each voxel centre in the affine's space."""
    index = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1).astype(np.float64)
    return index @ affine[:3, :3].T + affine[:3, 3]


def sphere_field(points: np.ndarray, centre, radius: float) -> np.ndarray:
    """Signed distance to a sphere, mm (negative inside)."""
    return np.linalg.norm(points - np.asarray(centre), axis=-1) - radius


def torus_field(points: np.ndarray, centre, major: float, minor: float, axis=(1.0, 2.0, 3.0)) -> np.ndarray:
    """Signed distance to a torus about ``axis`` through ``centre``, mm (negative inside); the default axis is
    tilted off the voxel axes, so that no row of voxels runs along the tube."""
    p = points - np.asarray(centre)
    normal = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    height = p @ normal
    ring = np.linalg.norm(p - height[..., None] * normal, axis=-1) - major
    return np.hypot(ring, height) - minor


def phantom(kind: str, voxel_mm: float, seed: int = 0):
    """(labels (i, j, k) uint8, RAS affine, centre mm, field function) of a sphere (label 1, radius 20 mm) or a
    torus (label 2, radii TORUS mm) voxelised at ``voxel_mm`` with the centre off the voxel grid."""
    rng = np.random.default_rng(seed)
    extent = 34.0 if kind == "sphere" else 46.0
    count = int(np.ceil(2 * extent / voxel_mm)) + 1
    affine = grid_affine(voxel_mm, [-extent, -extent + 3.0, -extent + 50.0])
    centre = np.array([0.0, 3.0, 50.0]) + rng.uniform(-0.5, 0.5, 3) * voxel_mm
    points = voxel_centres((count, count, count), affine)
    if kind == "sphere":
        def field(p):
            return sphere_field(p, centre, 20.0)
        value = 1
    else:
        def field(p):
            return torus_field(p, centre, TORUS[0], TORUS[1])
        value = 2
    labels = np.where(field(points) <= 0, value, 0).astype(np.uint8)
    return labels, affine, centre, field


def write_nifti(path: Path, data: np.ndarray, affine: np.ndarray) -> Path:
    nib.save(nib.Nifti1Image(data, affine), str(path))
    return path


def write_nrrd(path: Path, data: np.ndarray, affine_lps: np.ndarray, extra: dict | None = None,
               layered: bool = False) -> Path:
    """An NRRD in LPS space (gzip), a 4-D label map with a list axis first when ``layered``."""
    directions = [list(column) for column in affine_lps[:3, :3].T]
    header = {"space": "left-posterior-superior", "space origin": affine_lps[:3, 3].tolist(),
              "space directions": np.array(([[np.nan] * 3] if layered else []) + directions, dtype=float),
              "encoding": "gzip",
              "kinds": (["list"] if layered else []) + ["domain"] * 3}
    header.update(extra or {})
    nrrd.write(str(path), data, header, custom_field_map={key: "string" for key in extra or {}})
    return path


def write_dicom_series(folder: Path, hu: np.ndarray, affine_lps: np.ndarray, slope: float = 1.0,
                       intercept: float = -1024.0, names=None) -> Path:
    """One uncompressed CT slice file per k of ``hu`` ((i, j, k) Hounsfield units, i along a row), stored as
    (HU - intercept) / slope; files named by ``names(k)`` (default: reversed order, so name order is wrong)."""
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder.mkdir(parents=True, exist_ok=True)
    series = generate_uid()
    stored = np.rint((hu - intercept) / slope).astype(np.uint16)
    spacing = np.linalg.norm(affine_lps[:3, :3], axis=0)
    unit = affine_lps[:3, :3] / spacing
    count = hu.shape[2]
    for k in range(count):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        name = names(k) if names else f"slice_{count - 1 - k:03d}.dcm"
        ds = FileDataset(str(folder / name), {}, file_meta=meta, preamble=b"\0" * 128)
        ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.Modality, ds.SeriesInstanceUID, ds.StudyInstanceUID = "CT", series, series
        ds.ContentDate = datetime.date.today().strftime("%Y%m%d")
        ds.ImagePositionPatient = [float(v) for v in affine_lps[:3, 3] + k * affine_lps[:3, 2]]
        ds.ImageOrientationPatient = [float(v) for v in (*unit[:, 0], *unit[:, 1])]
        ds.PixelSpacing = [float(spacing[1]), float(spacing[0])]
        ds.SliceThickness = float(spacing[2])
        ds.Rows, ds.Columns = hu.shape[1], hu.shape[0]
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
        ds.RescaleSlope, ds.RescaleIntercept = slope, intercept
        ds.PixelData = np.ascontiguousarray(stored[:, :, k].T).tobytes()
        ds.save_as(str(folder / name), enforce_file_format=True)
    return folder
