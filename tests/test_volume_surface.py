"""volume.surface.label_surface: the triangles of a label's reconstructed surface lie where the slice prints the
boundary: for the 3 mm sphere phantom, every vertex within 0.35 voxel of the true sphere (the printed boundary's
bound), closed (every edge shared by two triangles)."""

from __future__ import annotations

import numpy as np
from test_volume_accuracy import load_phantom

from heoslice.volume.placement import place
from heoslice.volume.resample import label_print
from heoslice.volume.surface import label_surface


def test_sphere_surface_lies_on_the_sphere_and_is_closed(tmp_path):
    volume, field = load_phantom(tmp_path, "sphere", 3.0, "LPS", seed=5)
    plan = label_print(volume, place(volume), [(volume.labels[0], 1)])
    vertices, faces = label_surface(plan.fields[0], plan.origin, plan.spacing)
    error = field(vertices) / 3.0  # printer mm are RAS mm (up = S)
    assert len(faces) > 1000 and np.abs(error).max() <= 0.35
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert (uses == 2).all()
