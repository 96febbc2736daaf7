"""The volume route against the mesh route a user takes today, on a part of the shared 41-label map
(../shared/data/imaging; skipped when absent) and, in the slow set, on the whole map: each label meshed by scikit-image's marching cubes (level 0.5
of its 0/1 voxels, in the file's RAS millimetres) and sliced by heoslice's mesh path is the test-only
reference; each label's printed boundary lies within one voxel (3 mm) of the reference's, both ways,
everywhere (the largest 3D distance from a boundary pixel of one stack to the other's boundary)."""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest
from scipy import ndimage

from heoslice.layers import plane_heights, slice_mesh
from heoslice.layers.contours import build_contours
from heoslice.layers.rasterising import grid_for, solid_mask
from heoslice.volume import load_volume
from heoslice.volume.placement import place
from heoslice.volume.resample import label_print, layer_masks

pytestmark = pytest.mark.shared_data

#: The part of the map compared in the quick suite (voxel index ranges i, j, k): 23 structures (organs, vessels,
#: vertebrae, ribs), cut flat at its faces as a field of view cuts a scan; the slow set compares the whole map.
CROP = (slice(40, 80), slice(20, 60), slice(8, 22))
WHOLE = (slice(None), slice(None), slice(None))
LAYER_MM, DPI = 0.5, 50.0


def marching_cubes_masks(data, affine, values, z, grid):
    """The mesh route: each label's marching-cubes mesh (RAS mm, outward faces) sliced at heights ``z`` and
    filled at ``grid``'s pixels: {value: (layers, H, W) bool}."""
    from skimage.measure import marching_cubes

    masks = {}
    for value in values:
        verts, faces, _, _ = marching_cubes(np.pad(data == value, 1).astype(np.float32), 0.5)
        verts = (verts - 1.0) @ affine[:3, :3].T + affine[:3, 3]
        contours = build_contours(slice_mesh(verts, faces[:, ::-1], z), hierarchy=False)
        stack = np.zeros((len(z), grid.height, grid.width), dtype=bool)
        for layer in range(len(z)):
            first, stop = contours.layer_offsets[layer], contours.layer_offsets[layer + 1]
            if stop > first:
                offsets = contours.offsets[first:stop + 1]
                stack[layer] = solid_mask(contours.points[offsets[0]:offsets[-1]], offsets - offsets[0], grid)
        masks[value] = stack
    return masks


def boundary_gap_mm(first: np.ndarray, second: np.ndarray, spacing) -> float:
    """The largest distance (mm) from a boundary voxel of either (layers, H, W) mask to the other's boundary
    (a set voxel with an unset 6-neighbour, the stack's outside unset)."""
    boundaries = [mask & ~ndimage.binary_erosion(mask, border_value=0) for mask in (first, second)]
    both = np.argwhere(boundaries[0] | boundaries[1])
    low, high = both.min(axis=0), both.max(axis=0) + 1
    box = tuple(slice(a, b) for a, b in zip(low, high))
    gaps = [ndimage.distance_transform_edt(~other[box], sampling=spacing)[one[box]].max()
            for one, other in (boundaries, boundaries[::-1])]
    return float(max(gaps))


@pytest.mark.parametrize("crop", [CROP, pytest.param(WHOLE, marks=pytest.mark.slow)], ids=["part", "whole"])
def test_each_label_lies_within_a_voxel_of_its_marching_cubes_mesh(shared_data, tmp_path, crop):
    """Every label of the part, or of the whole map (its own material code, 50 dpi, 0.5 mm layers): the largest
    distance between its printed boundary and its marching-cubes mesh's sliced boundary is at most one voxel."""
    image = nib.load(shared_data / "imaging" / "example_seg.nii.gz")
    data = np.asarray(image.dataobj)[crop]
    affine = image.affine.copy()
    affine[:3, 3] = image.affine[:3, :3] @ [piece.start or 0 for piece in crop] + image.affine[:3, 3]
    nib.save(nib.Nifti1Image(data, affine), tmp_path / "part.nii.gz")
    volume = load_volume(tmp_path / "part.nii.gz")
    assert len(volume.labels) >= 20
    plan = label_print(volume, place(volume), [(label, code + 1) for code, label in enumerate(volume.labels)])
    bounds = plan.bounds_mm()
    grid = grid_for(bounds[:, :2], (DPI, DPI), 1.0)
    z = plane_heights(bounds[0, 2], bounds[1, 2], LAYER_MM)
    printed = np.zeros((len(volume.labels), len(z), grid.height, grid.width), dtype=bool)
    for layer, height in enumerate(z):
        planes, _ = layer_masks(plan, float(height), grid, len(volume.labels))
        printed[:, layer] = np.unpackbits(planes[1:], axis=2, count=grid.width).astype(bool)
    reference = marching_cubes_masks(data, affine, [label.value for label in volume.labels], z, grid)
    voxel = float(abs(affine[0, 0]))
    gaps = {label.value: boundary_gap_mm(printed[code], reference[label.value], (LAYER_MM, grid.py, grid.px))
            for code, label in enumerate(volume.labels)}
    in_voxels = {value: round(gap / voxel, 2) for value, gap in gaps.items()}
    assert max(in_voxels.values()) <= 1.0, in_voxels
    if crop == WHOLE:
        assert len(in_voxels) == 41, in_voxels
