"""Droplet masks and preview colours of a layer whose every solid pixel has its own material mix: the ``field``
interior (:mod:`heoslice.material.field`), halftoned by the graded layers' own compiled ordered dither
(:func:`heoslice.grading.droplets_kernels.droplet_bits`, one lattice cell per pixel), so a pixel of mix m jets
what a graded pixel of that mix jets."""

from __future__ import annotations

import numpy as np

from heoslice.grading.droplets_kernels import Dither, LabelledLayer, LayerMixes, droplet_bits
from heoslice.grading.halftone import TILE, layer_tile
from heoslice.grading.spec import GradeSpec
from heoslice.layers.rasterising import Grid


def solid_pixels(packed: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) (n,) int64 of the solid pixels of a packed layer mask ((h, ceil(w / 8)) uint8, MSB first)."""
    mask = np.unpackbits(packed, axis=1, count=width).view(bool)
    rows, cols = np.nonzero(mask)
    return rows.astype(np.int64), cols.astype(np.int64)


def field_mix(field, spec: GradeSpec, rows: np.ndarray, cols: np.ndarray, grid: Grid, z: float) -> np.ndarray:
    """Each solid pixel's mix over ``spec.channel_materials()`` ((n, K) float): 1 - f of the design's start and f
    of its target, f = f(r) at the pixel centre's own 3-D r (:meth:`heoslice.material.field.MaterialField.layer_r`)."""
    design = field.design
    f = field.fraction(field.layer_r(rows, cols, grid, z))
    mix = np.zeros((len(f), len(spec.channel_materials())))
    mix[:, spec.channel_index(_as_channel(spec, design.start))] = 1.0 - f
    mix[:, spec.channel_index(_as_channel(spec, design.target))] += f
    return mix


def _as_channel(spec: GradeSpec, material):
    """The droplet-mask material of ``spec`` that is ``material`` (by name and colour; its channel may have been
    assigned since)."""
    return next(m for m in spec.channel_materials() if (m.name, m.color) == (material.name, material.color))


def pixel_mix_planes(packed: np.ndarray, rows: np.ndarray, cols: np.ndarray, mix: np.ndarray, grid: Grid,
                     layer: int, base_channel: int) -> np.ndarray:
    """The droplet masks ((K, h, ceil(w / 8)) uint8, bit-packed) of a layer whose solid pixels (rows, cols (n,),
    every solid pixel of ``packed``) have the mixes ``mix`` ((n, K) float, rows summing to 1): the layer's
    ordered dither picks each pixel's material (:func:`droplet_bits` with a cell per pixel)."""
    channels = mix.shape[1]
    planes = np.zeros((channels, grid.height, -(-grid.width // 8)), dtype=np.uint8)
    if not len(rows):
        return planes
    r0, c0 = int(rows.min()), int(cols.min())
    height, width = int(rows.max()) - r0 + 1, int(cols.max()) - c0 + 1
    cells = np.zeros((height, width, channels), dtype=np.float32)
    cells[rows - r0, cols - c0] = mix
    label = np.broadcast_to(np.ones((1, width), dtype=np.uint8), (height, width))
    table = np.full((2, TILE * TILE), -1, dtype=np.int8)
    table[0] = base_channel
    mixing = LayerMixes(np.zeros(2, np.int64), np.zeros(2), np.array([[r0, c0, 1, width, 0]], np.int64),
                        cells.ravel(), np.zeros(channels))
    return droplet_bits(LabelledLayer(label, r0, c0, packed), mixing,
                        Dither(layer_tile(layer), table, base_channel), planes)


def pixel_mix_colors(mix: np.ndarray, spec: GradeSpec) -> np.ndarray:
    """The display colour (n, 3) float 0..255 of each pixel's mix ((n, K)): the materials' colours mixed (eq. 1)."""
    palette = np.array([m.color for m in spec.channel_materials()], dtype=np.float64)
    return mix @ palette
