"""A label's reconstructed surface as triangles, the surface a grading inside a label measures distances from
(a liver graded toward its tumour: the tumour's surface).

Marching cubes (scikit-image's, the maintained implementation) of the label's smooth field
(:mod:`heoslice.volume.fields`) at level 0, the field first sampled trilinearly SUPERSAMPLE times per voxel
along each axis: the triangles then follow the printed boundary (the same field, interpolated trilinearly at
the pixels) to a small part of a voxel, not the voxels' stair steps.
"""

from __future__ import annotations

import numpy as np

from heoslice.volume.fields import FAR_OUTSIDE, LabelField, supersampled

#: Samples per voxel along each axis the field is interpolated at before marching cubes.
SUPERSAMPLE = 2


def label_surface(field: LabelField, origin: np.ndarray, spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) float64, printer x, y, z mm; faces (m, 3) int64) of ``field``'s zero level, closed (the
    field is taken as far outside beyond its box). ``origin``: printer (z, y, x) mm of the oriented grid's index
    (0, 0, 0); ``spacing``: (3,) mm, its voxel size along z, y, x."""
    from skimage.measure import marching_cubes

    fine = np.pad(supersampled(field.values, SUPERSAMPLE), 1, constant_values=FAR_OUTSIDE)
    vertices, faces, _, _ = marching_cubes(fine, 0.0)
    voxel = (vertices - 1.0 + 0.5) / SUPERSAMPLE - 0.5 + field.start  # sample s of voxel i: i + (s + 1/2) / f - 1/2
    millimetres = np.asarray(origin) + voxel * np.asarray(spacing)
    return np.ascontiguousarray(millimetres[:, ::-1], dtype=np.float64), faces.astype(np.int64)
