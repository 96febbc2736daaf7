"""The field interior's compiled ordered dither of a closed-form reference (grading/pixel_mix_kernels.py): its masks
are bit for bit those of the rule written out in numpy (each solid pixel's r from the squared distance, its table
index, the table's levels under f, the comparison with the pixel's dither level), for point, tilted plane and axis
references, boxes that start inside the layer, grids whose width is not whole bytes, runs of solid bytes with gaps,
and any order of the start and target channels; and of a surface reference's steps per pixel (step_planes), the
same rule from the steps given."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.grading.halftone import LEVELS, layer_tile
from heoslice.grading.pixel_mix_kernels import quadratic_planes, step_planes
from heoslice.material.field import solid_box
from heoslice.material.references import Reference, grid_square

REFERENCES = {"point": Reference("point", (0.3, -0.2, 0.1)),
              "plane": Reference("plane", (0.3, -0.2, 0.1), tuple(np.array([1.0, 2.0, 2.0]) / 3.0)),
              "axis": Reference("axis", (0.3, -0.2, 0.1), tuple(np.array([2.0, -1.0, 2.0]) / 3.0))}


def numpy_planes(solid: np.ndarray, row0: int, c0: int, frame, square, r_range, below, level, start, target,
                 channels) -> np.ndarray:
    """The rule of quadratic_planes pixel by pixel in numpy, in the same float64 operations: unpacked masks
    (channels, h, w) bool of a layer whose solid pixels (h, w) lie in rows row0.. and columns c0.."""
    a, b, c, d, e, f = square
    r0, r1 = r_range
    rows, cols = np.nonzero(solid)
    u = frame[0] + (cols - c0) * frame[1]
    v = frame[2] + (rows - row0) * frame[3]
    q = (a * u + (b * v + d)) * u + ((c * v + e) * v + f)
    r = np.minimum(np.maximum((np.sqrt(np.maximum(q, 0.0)) - r0) * (1.0 / (r1 - r0)), 0.0), 1.0)
    k = (r * (len(below) - 1) + 0.5).astype(np.int64)
    n = level.shape[0]
    jets = level[rows % n, cols % n] < below[k]
    masks = np.zeros((channels, *solid.shape), dtype=bool)
    masks[start, rows, cols] = ~jets
    masks[target, rows, cols] |= jets
    return masks


def kernel_masks(solid: np.ndarray, reference: Reference, z: float, px: float, layer: int, below: np.ndarray,
                 r_range, start: int, target: int, channels: int,
                 method: str = "ordered") -> tuple[np.ndarray, np.ndarray]:
    """(quadratic_planes' masks, numpy_planes' masks), both unpacked, of a solid layer on a grid from (-6, 6) mm."""
    height, width = solid.shape
    packed = np.packbits(solid, axis=1)
    row0, row1, c0, _ = solid_box(packed, width)
    p = reference.point
    frame = (-6.0 + (c0 + 0.5) * px - p[0], px, 6.0 - (row0 + 0.5) * px - p[1], -px)
    square = grid_square(reference, z)
    level = np.ascontiguousarray(np.rint(layer_tile(layer, method) * LEVELS - 0.5), dtype=np.int32)
    planes = np.zeros((channels, height, packed.shape[1]), dtype=np.uint8)
    quadratic_planes(np.ascontiguousarray(packed[row0:row1]), row0, c0, frame, square, *r_range, below, level,
                     start, target, planes)
    expected = numpy_planes(solid, row0, c0, frame, square, r_range, below, level, start, target, channels)
    return np.unpackbits(planes, axis=2, count=width).astype(bool), expected


@pytest.mark.parametrize("method", ["ordered", "blue-noise"])
@pytest.mark.parametrize("kind", sorted(REFERENCES))
@pytest.mark.parametrize("start, target, channels", [(0, 1, 2), (1, 0, 2), (2, 0, 3)])
def test_masks_are_the_numpy_rule_bit_for_bit(kind, start, target, channels, method):
    """Random solid pixels (gaps of zero bytes inside rows, short and long, an empty row, a box from row 7 and
    column 19 on a 121-pixel-wide grid) and a
    table of levels that is not monotone in r: the kernel's masks equal the rule's, with the 16-pixel ordered
    tile and the 64-pixel blue-noise one; every solid pixel jets one of the two channels, no other pixel any."""
    rng = np.random.default_rng(len(kind) + 10 * start)
    solid = rng.random((90, 121)) < 0.7
    solid[:7] = False
    solid[:, :19] = False
    solid[40:44, 50:90] = False  # whole zero bytes between runs
    solid[60:66, 24:88] = False  # eight of them, then a solid byte
    solid[70] = False
    below = rng.integers(0, LEVELS + 1, 65536).astype(np.uint16)
    got, expected = kernel_masks(solid, REFERENCES[kind], 1.7, 0.1, 5, below, (0.5, 9.0), start, target,
                                 channels, method)
    assert np.array_equal(got, expected)
    assert (got.sum(axis=0) == solid).all()


@pytest.mark.parametrize("layer", [0, 1, 6, 200])
def test_the_dither_phase_follows_the_absolute_row_and_column(layer):
    """A ramp of r across a box that starts off the 16-pixel tile in both directions: each layer's tile (its own
    flips) read at the pixel's absolute row and column, as the rule and the layer's other dithers read it."""
    solid = np.zeros((70, 203), dtype=bool)
    solid[5:63, 9:200] = True
    below = np.minimum(np.arange(65536) // 200, LEVELS).astype(np.uint16)
    got, expected = kernel_masks(solid, REFERENCES["plane"], 0.4, 0.05, layer, below, (0.0, 12.0), 0, 1, 2)
    assert np.array_equal(got, expected)


def test_a_reference_outside_the_range_clips_r():
    """A point at the layer's centre with R0 above the nearest pixels' distance and R1 below the farthest: r
    clips to 0 inside R0 and to 1 beyond R1 (the table's first and last entries), bit for bit."""
    solid = np.ones((64, 64), dtype=bool)
    below = np.full(65536, 100, dtype=np.uint16)
    below[0], below[-1] = 0, LEVELS
    got, expected = kernel_masks(solid, Reference("point", (-4.4, 4.4, 0.0)), 0.0, 0.1, 3, below, (1.0, 3.0),
                                 0, 1, 2)
    assert np.array_equal(got, expected)
    assert not got[1][13:19, 13:19].any() and got[1][60:, 60:].all()


def numpy_step_planes(solid: np.ndarray, steps: np.ndarray, row0: int, c0: int, below, level, start, target,
                      channels) -> np.ndarray:
    """step_planes' rule pixel by pixel: each solid pixel (row, col) jets ``target`` where its dither level is
    under below[steps[row - row0, col - c0]], else ``start``; unpacked masks (channels, h, w) bool."""
    rows, cols = np.nonzero(solid)
    jets = level[rows % level.shape[0], cols % level.shape[0]] < below[steps[rows - row0, cols - c0]]
    masks = np.zeros((channels, *solid.shape), dtype=bool)
    masks[start, rows, cols] = ~jets
    masks[target, rows, cols] |= jets
    return masks


@pytest.mark.parametrize("method", ["ordered", "blue-noise"])
@pytest.mark.parametrize("start, target, channels, largest", [(0, 1, 2, 65536), (1, 0, 2, 1001), (2, 0, 3, 300)])
def test_step_planes_are_the_numpy_rule_with_anything_off_the_solid(start, target, channels, largest, method):
    """Random solid pixels in a box from row 7 and column 24 (gaps of whole zero bytes, an empty row, solid pixels
    in the last byte of a row 123 pixels wide, whose bits past the width the kernel reads too), steps under
    ``largest`` at solid pixels and anything up to 65535 elsewhere in the box (read before the solid masks them, so
    the table has an entry for every uint16): the masks equal the rule's (the ordered and the blue-noise tile),
    and every solid pixel jets one of the two channels, no other pixel any."""
    rng = np.random.default_rng(start + 7 * target + largest)
    solid = rng.random((90, 123)) < 0.7
    solid[:7] = False
    solid[:, :24] = False
    solid[:, 121:] = False
    solid[7:80, 120] = True
    solid[40:44, 50:90] = False
    solid[70] = False
    packed = np.packbits(solid, axis=1)
    row0, row1, c0, c1 = solid_box(packed, solid.shape[1])
    steps = rng.integers(0, 65536, (row1 - row0, c1 - c0)).astype(np.uint16)
    inside = solid[row0:row1, c0:c1]
    steps[inside] = rng.integers(0, largest, int(inside.sum()))
    below = rng.integers(0, LEVELS + 1, 65536).astype(np.uint16)
    level = np.ascontiguousarray(np.rint(layer_tile(3, method) * LEVELS - 0.5), dtype=np.int32)
    planes = np.zeros((channels, *packed.shape), dtype=np.uint8)
    step_planes(np.ascontiguousarray(packed[row0:row1]), row0, c0, steps, below, level, start, target, planes)
    got = np.unpackbits(planes, axis=2, count=solid.shape[1]).astype(bool)
    assert np.array_equal(got, numpy_step_planes(solid, steps, row0, c0, below, level, start, target, channels))
    assert (got.sum(axis=0) == solid).all()


def test_step_planes_refuse_a_table_without_an_entry_for_every_step():
    """A table shorter than 65536 entries would be read past its end by a step off the solid: ValueError."""
    packed = np.packbits(np.ones((4, 16), dtype=bool), axis=1)
    level = np.ascontiguousarray(np.rint(layer_tile(0) * LEVELS - 0.5), dtype=np.int32)
    with pytest.raises(ValueError, match="65536"):
        step_planes(packed, 0, 0, np.zeros((4, 16), np.uint16), np.zeros(1001, np.uint16), level, 0, 1,
                    np.zeros((2, 4, 2), np.uint8))
