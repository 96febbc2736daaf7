"""Tests of heoslice.volume.fields' volume-preserving level: the level set of a label's field holds its voxel
count, and with a ``taken`` field (the labels that win over it) it holds that count outside their region,
measured by dense trilinear sampling (an independent count)."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.volume.fields import level_offset, supersampled, voxel_distance

#: Dense samples per voxel along each axis for the reference count.
DENSE = 8


def dense_voxels(values: np.ndarray, taken: np.ndarray | None = None) -> float:
    """Voxels where the trilinear ``values`` are positive (and ``taken`` is not), counted at DENSE^3 points each."""
    inside = supersampled(values, DENSE) > 0
    if taken is not None:
        inside &= supersampled(taken, DENSE) <= 0
    return inside.sum() / DENSE ** 3


@pytest.mark.parametrize("cut", [6.3, 8.6, 10.2])
def test_level_holds_the_volume_outside_what_is_taken(cut):
    """A ball of voxels (radius 5, centre off the grid): alone, its level set holds its voxel count; with the
    box below x = ``cut`` taken (a plane off the grid, a quarter to most of the ball), the level drops so that
    the rest holds it (within 3 %)."""
    index = np.indices((20, 20, 20)).transpose(1, 2, 3, 0)
    mask = np.linalg.norm(index - np.array([9.3, 9.6, 9.8]), axis=-1) <= 5.0
    count = int(mask.sum())
    values = voxel_distance(mask)
    assert dense_voxels(values - np.float32(level_offset(values, count))) == pytest.approx(count, rel=0.03)
    taken = np.broadcast_to((cut - np.arange(20, dtype=np.float32))[None, None, :], mask.shape)
    level = level_offset(values, count, np.ascontiguousarray(taken))
    assert level < level_offset(values, count)
    assert dense_voxels(values - np.float32(level), taken) == pytest.approx(count, rel=0.03)
