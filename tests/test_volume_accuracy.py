"""Accuracy of the volume route against analytic phantoms voxelised by the test (a sphere of radius 20 mm and a
torus, at 3 mm and 1 mm voxels, centres off the voxel grid, stored in RAS and in LPS).

The printed boundary is located between each pair of neighbouring pixels of a layer that differ (in and
out); its radial error is the phantom's exact signed distance there, in voxels. Required: at most 0.15 voxel
RMS and 0.35 voxel at worst, and each label's printed volume within 1 % of the phantom's exact volume. The
metric's resolution-independence (what lets most cases run at 300 dpi and 0.5 mm layers) is itself tested
against the issue's 600 dpi and 0.1 mm on one phantom.
"""

from __future__ import annotations

import numpy as np
import pytest
from volume_phantoms import FLIP_XY, TORUS, phantom, write_dicom_series, write_nifti, write_nrrd

from heoslice.layers.rasterising import grid_for
from heoslice.volume import load_volume
from heoslice.volume.placement import place
from heoslice.volume.resample import label_print, layer_masks

EXACT_VOLUME = {"sphere": 4 / 3 * np.pi * 20.0 ** 3, "torus": 2 * np.pi ** 2 * TORUS[0] * TORUS[1] ** 2}


def sliced(volume, dpi: float, layer_mm: float, every: int = 1):
    """(boundary points (n, 3) mm, printed volume mm^3 of all layers, layer count) of ``volume``'s one label
    sliced at ``dpi`` and ``layer_mm``; boundary points from every ``every``-th layer only."""
    plan = label_print(volume, place(volume), [(volume.labels[0], 1)])
    bounds = plan.bounds_mm()
    grid = grid_for(bounds[:, :2], (dpi, dpi), 1.0)
    x, y = grid.centres()
    heights = np.arange(bounds[0, 2] + layer_mm / 2, bounds[1, 2], layer_mm)
    points, pixels = [], 0
    for number, z in enumerate(heights):
        if every > 1 and number % every:
            continue
        planes, counts = layer_masks(plan, float(z), grid, 1)
        pixels += int(counts[1])
        mask = np.unpackbits(planes[1], axis=1, count=grid.width).astype(bool)
        rows, columns = np.nonzero(mask[:, 1:] != mask[:, :-1])
        points.append(np.stack([(x[columns] + x[columns + 1]) / 2, y[rows], np.full(len(rows), z)], axis=-1))
        rows, columns = np.nonzero(mask[1:] != mask[:-1])
        points.append(np.stack([x[columns], (y[rows] + y[rows + 1]) / 2, np.full(len(rows), z)], axis=-1))
    return np.concatenate(points), pixels * grid.px * grid.py * layer_mm * every, len(heights)


def to_ras(points: np.ndarray, space: str) -> np.ndarray:
    """Printer mm (RAS, the default up) of points in a file's space: LPS points have x and y negated."""
    return points if space == "RAS" else points * np.array([-1.0, -1.0, 1.0])


def load_phantom(tmp_path, kind: str, voxel_mm: float, space: str, seed: int):
    labels, affine, centre, field = phantom(kind, voxel_mm, seed)
    if space == "RAS":
        path = write_nifti(tmp_path / "p.nii.gz", labels, affine)
    else:
        path = write_nrrd(tmp_path / "p.nrrd", labels, FLIP_XY @ affine)
    return load_volume(path), field


@pytest.mark.parametrize("space", ["RAS", "LPS"])
@pytest.mark.parametrize("voxel_mm", [3.0, 1.0])
@pytest.mark.parametrize("kind", ["sphere", "torus"])
def test_phantom_boundary_and_volume(tmp_path, kind, voxel_mm, space):
    """Radial error <= 0.15 voxel RMS and <= 0.35 voxel worst; printed volume within 1 % of the exact volume
    (300 dpi, 0.5 mm layers: see test_metric_is_resolution_independent)."""
    volume, field = load_phantom(tmp_path, kind, voxel_mm, space, seed=7)
    points, printed, _ = sliced(volume, 300.0, 0.5)
    error = field(points) / voxel_mm  # the printer's frame is RAS: the phantom's field is in RAS mm
    assert np.sqrt(np.mean(error ** 2)) <= 0.15
    assert np.abs(error).max() <= 0.35
    assert abs(printed / EXACT_VOLUME[kind] - 1) <= 0.01


def test_metric_is_resolution_independent_and_holds_at_600_dpi_and_0_1_mm(tmp_path):
    """The 3 mm sphere at the issue's 600 dpi and 0.1 mm layers (every 10th layer): within the bounds, and its
    RMS error within 0.01 voxel of the 300 dpi / 0.5 mm figure on the same phantom."""
    volume, field = load_phantom(tmp_path, "sphere", 3.0, "RAS", seed=11)
    fine, _, count = sliced(volume, 600.0, 0.1, every=10)
    coarse, _, _ = sliced(volume, 300.0, 0.5)
    fine_error, coarse_error = field(fine) / 3.0, field(coarse) / 3.0
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    assert count >= 400 and rms(fine_error) <= 0.15 and np.abs(fine_error).max() <= 0.35
    assert abs(rms(fine_error) - rms(coarse_error)) <= 0.01


def test_nearest_voxel_blocks_would_fail(tmp_path):
    """The bounds are not loose: printing the 3 mm sphere's voxels as blocks (no smoothing, --smooth 0 and
    the union's field replaced by the labels') misses them."""
    volume, field = load_phantom(tmp_path, "sphere", 3.0, "RAS", seed=7)
    plan = label_print(volume, place(volume), [(volume.labels[0], 1)], smooth=0.0)
    bounds = plan.bounds_mm()
    grid = grid_for(bounds[:, :2], (150.0, 150.0), 1.0)
    x, y = grid.centres()
    errors = []
    for z in np.arange(bounds[0, 2] + 0.25, bounds[1, 2], 1.0):
        planes, _ = layer_masks(plan, float(z), grid, 1)
        mask = np.unpackbits(planes[1], axis=1, count=grid.width).astype(bool)
        rows, columns = np.nonzero(mask[:, 1:] != mask[:, :-1])
        errors.append(field(np.stack([(x[columns] + x[columns + 1]) / 2, y[rows], np.full(len(rows), z)], -1)) / 3.0)
    error = np.concatenate(errors)
    assert np.sqrt(np.mean(error ** 2)) > 0.15


def test_dicom_series_and_its_nifti_land_on_the_same_pixels(tmp_path):
    """A phantom written as a DICOM series (LPS, slices named against their order) and as a NIfTI of the same
    voxels (RAS) give identical masks on every layer."""
    labels, affine, _, _ = phantom("sphere", 3.0, seed=3)
    values = np.where(labels > 0, 1000.0, 0.0).astype(np.float32)
    dicom = load_volume(write_dicom_series(tmp_path / "ct", values, FLIP_XY @ affine, intercept=0.0), "labels")
    nifti = load_volume(write_nifti(tmp_path / "ct.nii.gz", (labels > 0).astype(np.int16) * 1000, affine))
    assert dicom.space == "LPS" and nifti.space == "RAS"
    plans = [label_print(v, place(v), [(v.labels[0], 1)]) for v in (dicom, nifti)]
    assert np.allclose(plans[0].bounds_mm(), plans[1].bounds_mm())
    bounds = plans[0].bounds_mm()
    grid = grid_for(bounds[:, :2], (200.0, 200.0), 1.0)
    for z in np.arange(bounds[0, 2] + 0.25, bounds[1, 2], 2.0):
        first, second = (layer_masks(plan, float(z), grid, 1)[0] for plan in plans)
        assert np.array_equal(first, second)
