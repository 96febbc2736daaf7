"""Droplet masks: which of K materials each solid pixel jets, from the material fractions (halftoning).

A jetting printer puts one droplet of one material per pixel, so a graded layer
(fractions of K materials per pixel) becomes K 1-bit masks, each solid pixel in exactly
one. Three methods (:data:`METHODS`), each exact in expectation:

- ``ordered``: each pixel compares one threshold t in [0, 1) from an ordered-dither matrix
  (Bayer 16 x 16: every aligned 16 x 16 tile holds each of the 256 thresholds once, so over
  an area of constant mix each material's share is its fraction to within 1/256 plus the
  partial tiles at the border) with the running sum of the fractions: the pixel takes the
  first material whose cumulative fraction exceeds t. Layers are decorrelated by flipping
  the matrix's rows and columns per layer so that each pixel's threshold runs through
  [0, 1) evenly from layer to layer (:func:`ordered_flips`).
- ``blue-noise``: the same comparison with the thresholds of a 64 x 64 void-and-cluster
  mask (Ulichney 1993, :func:`blue_noise_ranks`: each of the 4096 levels once, without a
  lattice of its own), made by this module deterministically once per process, shifted
  per layer by a rank-1 lattice over the tile (:func:`blue_noise_shift`: 4096 consecutive
  layers take every shift once).
- ``error-diffusion``: vector error diffusion of the mix (:mod:`heoslice.grading.diffusion`).

Empty pixels get no material. :func:`halftone` is the method-independent entry point on a
per-pixel mix; a graded slice's layers go through :mod:`heoslice.grading.droplets`, which
gives the same masks without the per-pixel mix array.
"""

from __future__ import annotations

import functools

import numpy as np

#: The halftoning methods by name (``slice --halftone``, the manifest's ``grading.halftone``), each with a line
#: on what it gives; the first is the default.
METHODS = {
    "ordered": "a 16 x 16 Bayer matrix shifted per layer (a faint 16-pixel lattice)",
    "blue-noise": "a 64 x 64 void-and-cluster mask shifted per layer (no lattice)",
    "error-diffusion": "serpentine vector error diffusion, part of the error carried to the next layer "
                       "(the least low-frequency noise; the slowest)",
}
DEFAULT_METHOD = "ordered"
#: The methods that compare each pixel with a threshold tile of LEVELS levels (:func:`layer_tile`); error diffusion
#: has none.
THRESHOLD_METHODS = ("ordered", "blue-noise")

#: Side of the ordered-dither matrix (256 threshold levels).
TILE = 16
#: Threshold levels of every threshold tile: (k + 1/2) / LEVELS, k = 0 .. LEVELS - 1.
LEVELS = TILE * TILE
#: Side of the blue-noise threshold mask (4096 levels), and the void-and-cluster filter's sigma (pixels).
BLUE_TILE = 64
_BLUE_SIGMA = 1.5
#: The (row, column) flips of one bit of the position, by base-4 digit of the layer number: each pixel's digit of
#: the Bayer value then steps 0, 2, 1, 3 (or a rotation of it) over 4 layers: halves alternate, then quarters.
_FLIPS = ((0, 0), (0, 1), (1, 1), (1, 0))
#: Step of the blue-noise shift along the tile's 4096 offsets: odd (so 4096 layers take every offset once) and
#: near 4096 / golden ratio (so consecutive layers' offsets lie far apart in both directions).
_BLUE_STEP = 2531


def check_method(method: str) -> str:
    """``method`` when it names a halftoning method; ValueError naming the methods otherwise."""
    if method not in METHODS:
        raise ValueError(f"halftone: unknown method {method!r}; choose one of {', '.join(METHODS)}")
    return method


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


def _hashed_unit(count: int, seed: int) -> np.ndarray:
    """(count,) floats in [0, 1) from a fixed integer hash (splitmix64) of 0 .. count - 1: the same on every
    machine and numpy version, unlike a random generator's streams."""
    with np.errstate(over="ignore"):
        z = np.arange(count, dtype=np.uint64) + np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z ^= z >> np.uint64(31)
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def _wrapped_gaussian(values: np.ndarray, sigma: float) -> np.ndarray:
    """(n, n) float64: ``values`` filtered by a Gaussian of ``sigma`` pixels wrapped around the tile, separably (rows,
    then columns), the kernel cut at 4 sigma and summing to 1 (scipy.ndimage.gaussian_filter's, without loading
    scipy, whose import is a large share of a slice process's start-up: benchmarks/README.md)."""
    radius = int(4.0 * sigma + 0.5)
    offsets = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 * (offsets / sigma) ** 2)
    weights /= weights.sum()
    for axis in (0, 1):
        values = sum(weight * np.roll(values, -offset, axis=axis) for offset, weight in zip(offsets, weights))
    return values


@functools.cache
def blue_noise_ranks(size: int = BLUE_TILE, sigma: float = _BLUE_SIGMA) -> np.ndarray:
    """The (size, size) void-and-cluster rank matrix (0 .. size^2 - 1, Ulichney 1993), read-only; made once per
    process (compiled: :func:`heoslice.grading.halftone_kernels._void_and_cluster`).

    The energy of a pattern is its Gaussian filtering (``sigma`` pixels, wrapped around the tile), kept up to
    date by adding or removing one wrapped impulse response per pixel. A hashed 10 % initial pattern is
    relaxed (its tightest cluster moved to its largest void until that is the same pixel); its pixels are
    ranked by removing the tightest cluster one at a time, and the rest by filling the largest void one at a
    time (ties: the first in row-major order)."""
    from heoslice.grading.halftone_kernels import _void_and_cluster  # compiled: loaded by the methods that need it

    impulse = np.zeros((size, size))
    impulse[0, 0] = 1.0
    tiled = np.tile(_wrapped_gaussian(impulse, sigma), (2, 2))
    ones = (_hashed_unit(size * size, 1) < 0.1).reshape(size, size)
    energy = _wrapped_gaussian(ones.astype(np.float64), sigma)
    ranks = _void_and_cluster(ones, energy, tiled)
    ranks.setflags(write=False)
    return ranks


def blue_noise_shift(layer: int, size: int = BLUE_TILE) -> tuple[int, int]:
    """The (row, column) toroidal shift of the blue-noise mask in ``layer``: offset (layer * step) mod size^2
    of the tile, a rank-1 lattice (a full cycle: ``size``^2 consecutive layers take every shift once)."""
    offset = (int(layer) * _BLUE_STEP) % (size * size)
    return divmod(offset, size)


def blue_noise_thresholds(layer: int) -> np.ndarray:
    """(BLUE_TILE, BLUE_TILE) float: the blue-noise mask of ``layer`` at every one of its levels, (rank + 1/2) /
    BLUE_TILE^2 (error diffusion starts its regions from it)."""
    return (np.roll(blue_noise_ranks(), blue_noise_shift(layer), axis=(0, 1)) + 0.5) / (BLUE_TILE * BLUE_TILE)


def layer_tile(layer: int, method: str = DEFAULT_METHOD) -> np.ndarray:
    """The (n, n) thresholds in (0, 1) of one layer (n = TILE for ordered, BLUE_TILE for blue noise), at the
    LEVELS levels (k + 1/2) / LEVELS: ordered, the Bayer matrix with its rows and columns flipped by the layer's
    :func:`ordered_flips`; blue noise, the void-and-cluster mask under the layer's shift, its
    ranks taken 16 to a level (each level on 16 pixels of the tile: the shares as fine as ordered dither's, and
    the compiled halftone's table of choices per level as small)."""
    if check_method(method) == "blue-noise":
        ranks = np.roll(blue_noise_ranks(), blue_noise_shift(layer), axis=(0, 1))
        return (ranks // (BLUE_TILE * BLUE_TILE // LEVELS) + 0.5) / LEVELS
    if method not in THRESHOLD_METHODS:
        raise ValueError(f"halftone: {method} has no threshold tile")
    flip_rows, flip_cols = ordered_flips(layer)
    index = np.arange(TILE)
    return (bayer_matrix(TILE)[np.ix_(index ^ flip_rows, index ^ flip_cols)] + 0.5) / (TILE * TILE)


def ordered_flips(layer: int) -> tuple[int, int]:
    """The (row, column) masks whose XOR with a pixel's position in the tile reads the Bayer matrix in ``layer``.

    The Bayer matrix's value at (r, c) is, from its most significant base-4 digit down, the 2 x 2 matrix
    [[0, 2], [3, 1]] at bit 0 of r and c, then at bit 1, and so on; flipping bit j of the position permutes
    digit j of every pixel's value. Bit j's flips follow base-4 digit j of the layer number through
    :data:`_FLIPS`, so every pixel's threshold steps through the four quarters of [0, 1) every 4 layers
    (0, 1/2, 1/4, 3/4 or a rotation of it), its next digit every 16, and so on (a van der Corput sequence per
    pixel): over any 4 consecutive layers every pixel jets a material of share 1/4 or more at least once
    (columns that never change material, issue 48's 3D criterion). The tiles repeat every 256 layers."""
    rows = cols = 0
    for bit in range(TILE.bit_length() - 1):
        row_flip, col_flip = _FLIPS[(int(layer) >> (2 * bit)) & 3]
        rows |= row_flip << bit
        cols |= col_flip << bit
    return rows, cols


def thresholds(shape: tuple[int, int], layer: int, origin: tuple[int, int] = (0, 0),
               method: str = DEFAULT_METHOD) -> np.ndarray:
    """(rows, cols) float32 thresholds of a pixel box whose top-left pixel is ``origin`` (row, col) of the layer.

    The tile is anchored to the layer's pixel grid, so boxes of the same layer agree.
    """
    tile = layer_tile(layer, method).astype(np.float32)
    size = tile.shape[0]
    rows = (np.arange(shape[0]) + origin[0]) % size
    cols = (np.arange(shape[1]) + origin[1]) % size
    return tile[np.ix_(rows, cols)]


def halftone(mix: np.ndarray, layer: int, method: str = DEFAULT_METHOD, carry=None,
             origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """The droplet masks ((K, rows, cols) bool) of a layer's per-pixel mix ((rows, cols, K) float, rows summing
    to 1 at solid pixels, all 0 at empty ones), the box's top-left pixel being ``origin`` of the layer: every
    solid pixel in exactly one mask, empty pixels in none.

    Ordered and blue noise: the pixel jets the first material whose running sum (float32) exceeds its
    threshold times the mix's total. Error diffusion: :func:`heoslice.grading.diffusion.diffuse_mix`, with
    ``carry`` (a :class:`heoslice.grading.diffusion.DiffusionCarry`, or None for a fresh start) the error the
    layer before left, updated in place for the next layer.
    """
    mix = np.asarray(mix, dtype=np.float32)
    if mix.ndim != 3 or mix.shape[2] < 1:
        raise ValueError(f"halftone: the mix must be (rows, cols, K) with K >= 1, not {mix.shape}")
    if check_method(method) == "error-diffusion":
        from heoslice.grading.diffusion import diffuse_mix  # the compiled kernels load with the method that needs them

        return diffuse_mix(mix, layer, carry, origin)
    count = mix.shape[2]
    total = np.zeros(mix.shape[:2], dtype=np.float32)
    for channel in range(count):  # summed in order, as the compiled path does
        total += mix[..., channel]
    threshold = thresholds(mix.shape[:2], layer, origin, method) * np.where(total > 0, total, np.float32(1.0))
    chosen = np.full(mix.shape[:2], count - 1, dtype=np.int64)
    running = np.zeros(mix.shape[:2], dtype=np.float32)
    undecided = np.ones(mix.shape[:2], dtype=bool)
    for channel in range(count - 1):
        running += mix[..., channel]
        here = undecided & (threshold < running)
        chosen[here] = channel
        undecided &= ~here
    return (chosen[None] == np.arange(count)[:, None, None]) & (total > 0)[None]
