"""Droplet masks: which of K materials each solid pixel jets, from the material fractions (halftoning).

A jetting printer puts one droplet of one material per pixel, so a graded layer
(fractions of K materials per pixel) becomes K 1-bit masks. Each pixel compares one
threshold t in [0, 1) from an ordered-dither matrix (Bayer 16 x 16: every aligned
16 x 16 tile holds each of the 256 thresholds once, so over an area of constant mix
each material's share is its fraction to within 1/256 plus the partial tiles at the
border) with the running sum of the fractions: the pixel takes the first material
whose cumulative fraction exceeds t. Every solid pixel gets exactly one material and
empty pixels none.

Layers are decorrelated by a per-layer shift and one of the 8 symmetries of the
matrix (so droplets of the same material do not stack in the same columns), all
vectorised: the threshold image is an indexed tile, no loop per pixel.
"""

from __future__ import annotations

import functools

import numpy as np

#: Side of the ordered-dither matrix (256 threshold levels).
TILE = 16


@functools.cache
def bayer_matrix(size: int = TILE) -> np.ndarray:
    """The (size, size) Bayer index matrix (0 .. size^2 - 1), size a power of two; made once per size
    (every graded layer asks for it) and read-only."""
    if size < 1 or size & (size - 1):
        raise ValueError(f"Bayer matrix size must be a power of two, got {size}")
    matrix = np.zeros((1, 1), dtype=np.int64)
    while matrix.shape[0] < size:
        matrix = np.block([[4 * matrix, 4 * matrix + 2], [4 * matrix + 3, 4 * matrix + 1]])
    matrix.setflags(write=False)
    return matrix


def layer_tile(layer: int) -> np.ndarray:
    """The (TILE, TILE) thresholds in (0, 1) of one layer: the Bayer matrix under a symmetry and shift
    chosen from the layer number (a fixed pseudo-random sequence), so consecutive layers differ."""
    mix = (int(layer) * 0x9E3779B1 + 0x7F4A7C15) & 0xFFFFFFFF
    tile = bayer_matrix(TILE)
    if mix & 1:
        tile = tile.T
    tile = np.rot90(tile, (mix >> 1) & 3)
    tile = np.roll(tile, ((mix >> 3) % TILE, (mix >> 11) % TILE), axis=(0, 1))
    return (tile + 0.5) / (TILE * TILE)


def thresholds(shape: tuple[int, int], layer: int, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """(rows, cols) float32 thresholds of a pixel box whose top-left pixel is ``origin`` (row, col) of the layer.

    The tile is anchored to the layer's pixel grid, so boxes of the same layer agree.
    """
    tile = layer_tile(layer).astype(np.float32)
    rows = (np.arange(shape[0]) + origin[0]) % TILE
    cols = (np.arange(shape[1]) + origin[1]) % TILE
    return tile[np.ix_(rows, cols)]
