"""Droplet masks and preview colours of a layer whose every solid pixel has its own share f of a target material
against a start material: the ``field`` interior (:mod:`heoslice.material.field`).

The masks are the graded layers' own compiled threshold dither
(:func:`heoslice.grading.droplets_kernels.droplet_bits`) with one label per dither level: a pixel jets the target
where its threshold t (one of the 256 levels (k + 1/2) / 256 of :mod:`heoslice.grading.halftone`, from the ordered or
the blue-noise tile) is below f, so every f between two levels decides alike, and a pixel's label is q + 1, q = the
number of levels below its f; the table of choices per label and level is then the whole halftone (no per-pixel
arithmetic in the kernel). Over each aligned tile of one f (16 x 16 ordered, 64 x 64 blue noise) the target's share is
q / 256, within 1/512 of f. A design's field (:func:`field_planes`) reads q from a table of f's levels at r's steps;
for a plane, point or axis the pixel's r, its q and its comparison with the threshold are made in one compiled pass
(:func:`heoslice.grading.pixel_mix_kernels.quadratic_planes`), the same rule.
"""

from __future__ import annotations

import functools

import numpy as np

from heoslice.grading.droplets_kernels import Dither, LabelledLayer, LayerMixes, droplet_bits
from heoslice.grading.halftone import DEFAULT_METHOD, THRESHOLD_METHODS, TILE, check_method, halftone, layer_tile
from heoslice.layers.rasterising import Grid

#: The dither's levels: an ordered tile holds each of them once, a blue-noise tile each on 16 pixels.
LEVELS = TILE * TILE


def levels_below(f: np.ndarray) -> np.ndarray:
    """q int64 of f's shape: how many of the dither levels (k + 1/2) / 256 lie below each f in [0, 1]."""
    f = np.asarray(f)
    q = np.array(f * np.float32(LEVELS) if f.dtype == np.float32 else f.astype(np.float64) * LEVELS)  # 0-d too
    q -= 0.5
    np.ceil(q, out=q)
    np.clip(q, 0, LEVELS, out=q)
    return q.astype(np.int64)


def fraction_planes(packed: np.ndarray, box: tuple[int, int, int, int], f: np.ndarray, grid: Grid, layer: int,
                    start: int, target: int, channels: int, method: str = DEFAULT_METHOD,
                    carry=None) -> np.ndarray:
    """The droplet masks ((channels, h, ceil(w / 8)) uint8, bit-packed) of a layer whose solid pixels (``packed``,
    every one inside ``box``: first row, end row, first column, end column) jet the ``target`` channel in the
    share f (in [0, 1], an array that broadcasts to the box; its values off the solid pixels are not read) and
    the ``start`` channel otherwise: by the layer's ordered or blue-noise tile (the module's rule), or by error
    diffusion through :func:`heoslice.grading.halftone.halftone` (``carry``: its layer carry)."""
    planes = np.zeros((channels, grid.height, -(-grid.width // 8)), dtype=np.uint8)
    row0, row1, col0, col1 = box
    if row1 <= row0 or col1 <= col0:
        return planes
    if check_method(method) not in THRESHOLD_METHODS:
        solid = np.unpackbits(packed[row0:row1], axis=1, count=grid.width)[:, col0:col1].view(bool)
        share = np.where(solid, np.broadcast_to(np.asarray(f, dtype=np.float32), solid.shape), np.float32(0))
        mix = np.zeros((*solid.shape, channels), dtype=np.float32)
        mix[..., start] = np.where(solid, np.float32(1) - share, np.float32(0))
        mix[..., target] += share
        masks = np.zeros((channels, row1 - row0, grid.width), dtype=bool)
        masks[:, :, col0:col1] = halftone(mix, layer, method, carry, origin=(row0, col0))
        planes[:, row0:row1] = np.packbits(masks, axis=2)
        return planes
    return label_planes(packed, box, level_labels(f), grid, layer, start, target, channels, method)


def level_labels(f: np.ndarray) -> np.ndarray:
    """The dither label (uint16, f's shape) of each f in [0, 1]: q + 1, q = :func:`levels_below` (the module's rule)."""
    return (levels_below(f) + 1).astype(np.uint16)


def label_planes(packed: np.ndarray, box: tuple[int, int, int, int], labels: np.ndarray, grid: Grid, layer: int,
                 start: int, target: int, channels: int, method: str = DEFAULT_METHOD) -> np.ndarray:
    """The droplet masks of :func:`fraction_planes` by the threshold tile of ``method`` (one of
    :data:`THRESHOLD_METHODS`), from each solid pixel's label (:func:`level_labels` of its f; uint16, broadcasting
    to ``box``) instead of f."""
    planes = np.zeros((channels, grid.height, -(-grid.width // 8)), dtype=np.uint8)
    row0, row1, col0, col1 = box
    if row1 <= row0 or col1 <= col0:
        return planes
    label = np.broadcast_to(np.asarray(labels, dtype=np.uint16), (row1 - row0, col1 - col0))
    table = np.full((LEVELS + 2, LEVELS), start, dtype=np.int8)
    table[1:] = np.where(np.arange(LEVELS)[None, :] < np.arange(LEVELS + 1)[:, None], target, start)
    labels = LEVELS + 2
    mixing = LayerMixes(np.zeros(labels, np.int64), np.zeros(labels), np.array([[row0, col0, 1, 1, 0]], np.int64),
                        np.zeros(channels), np.zeros(channels))
    return droplet_bits(LabelledLayer(label, row0, col0, packed), mixing,
                        Dither(layer_tile(layer, method), table, start), planes)


def field_planes(field, packed: np.ndarray, grid: Grid, z: float, layer: int, start: int, target: int,
                 channels: int, method: str = DEFAULT_METHOD) -> np.ndarray:
    """The droplet masks ((channels, h, ceil(w / 8)) uint8, bit-packed) of a layer cut at height z (mm) whose solid
    pixels (``packed``) jet the ``target`` channel in the share f(r) of a design's ``field``
    (:class:`heoslice.material.field.MaterialField`) at each pixel's own r, rounded to the field's steps, and the
    ``start`` channel otherwise: the module's rule with the threshold tile of ``method`` (one of
    :data:`THRESHOLD_METHODS`), q read from one table of f's levels per field."""
    below = _levels_table(field)
    square = field.layer_square(packed, grid, z)
    planes = np.zeros((channels, grid.height, -(-grid.width // 8)), dtype=np.uint8)
    box, steps = field.layer_steps(packed, grid, z) if square is None else (square.box, None)
    row0, row1, col0, _ = box
    if row1 <= row0:
        return planes
    from heoslice.grading.pixel_mix_kernels import quadratic_planes, step_planes

    level = np.ascontiguousarray(np.rint(layer_tile(layer, method) * LEVELS - 0.5), dtype=np.int32)  # 0 .. 255
    rows = np.ascontiguousarray(packed[row0:row1])
    if steps is not None:
        step_planes(rows, row0, col0, steps, _step_levels(field), level, start, target, planes)
    else:
        quadratic_planes(rows, row0, col0, square.frame, square.square, *square.r_range, below, level, start, target,
                         planes)
    return planes


@functools.lru_cache(maxsize=4)
def _step_levels(field) -> np.ndarray:
    """:func:`_levels_table` padded with zeros to an entry for every uint16 (65536,), as :func:`step_planes` reads
    it (a step off the solid, anything up to 65535, indexes it unclipped)."""
    below = _levels_table(field)
    return np.concatenate([below, np.zeros(65536 - len(below), dtype=below.dtype)])


@functools.lru_cache(maxsize=4)
def _levels_table(field) -> np.ndarray:
    """q (uint16, one per entry of the field's :attr:`fraction_table`): the dither levels below f at each of r's
    steps, made once per field (a process slices one design)."""
    return levels_below(field.fraction_table).astype(np.uint16)


def fraction_colors(f: np.ndarray, start_color, target_color) -> np.ndarray:
    """The display colour (n, 3) float 0..255 of each pixel's share f (n,): eq. 1's blend of the two colours."""
    start, target = (np.asarray(c, dtype=np.float64) for c in (start_color, target_color))
    return start + np.asarray(f, dtype=np.float64)[:, None] * (target - start)
