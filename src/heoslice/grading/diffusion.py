"""Error diffusion for K materials: each solid pixel takes the material nearest its mix plus the error that
reached it, and passes the difference on (the ``error-diffusion`` halftone of :mod:`.halftone`).

Vector error diffusion (Jarvis, Judice and Ninke's weights, serpentine rows) over the mix of K materials: the
material taken is the largest component of the corrected mix among those the pixel holds, so a region of
one material stays pure. A share :data:`LAYER_SHARE` of each pixel's error goes to the same pixel of the
next layer (:class:`DiffusionCarry`), so that a column that took one material is pushed towards the
others one layer up and columns do not line up from layer to layer; the rest goes to the pixels after it
in the layer. The error is carried from layer to layer within one run of planes of a slice (consecutive
layers rendered by one process, :func:`heoslice.pipeline.runs.slice_run`) and starts afresh at a run's
first layer, so a stack does not depend on how many processes made it; a layer without the layer before's
error starts from a small share of the error the blue-noise halftone would leave (:func:`fresh_error`), and
a region's first row from the blue-noise halftone's choice (:data:`TOP_SHARE`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.grading.diffusion_kernels import _diffuse, _pixel_mixes
from heoslice.grading.droplets_kernels import LabelledLayer, LayerMixes
from heoslice.jit import f32, i64

#: Jarvis, Judice and Ninke's weights (1976): this row (ahead of the pixel) and the two below it, columns
#: -2 .. 2 along the row's direction, summing to 1. Chosen by measurement: over a constant 30 % mix with 2 % of
#: the error carried between layers, the power below 2 cycles/mm was 0.89 against Floyd-Steinberg's four
#: weights' 1.43 and ordered dither's 4.11 (the periodogram of benchmarks/bench_halftone.py).
JARVIS_JUDICE_NINKE = np.array([[0, 0, 0, 7, 5], [3, 5, 7, 5, 3], [1, 3, 5, 3, 1]], dtype=np.float32) / 48
#: The share of a pixel's error carried to the same pixel of the next layer (the rest stays in the layer): a
#: little is enough to decorrelate the layers; more adds low-frequency noise (benchmarks/bench_halftone.py).
LAYER_SHARE = 0.02
#: The share of the blue-noise halftone's choice less the mix that a region's first row starts from: no error
#: reaches it from above, and without it a material of small share would start only rows into its region.
TOP_SHARE = 0.5


@dataclass(slots=True)
class DiffusionCarry:
    """The error a layer's diffusion leaves to the next: its layer index, the top-left pixel (row, col) of the
    box it covers, and per pixel of the box the error per material ((rows, cols, K) float32). State handed
    from one layer to the next, not a cache: it changes what the next layer jets."""

    layer: int = -1
    origin: tuple[int, int] = (0, 0)
    error: np.ndarray | None = None

    def incoming(self, layer: int, origin: tuple[int, int], mix: np.ndarray) -> np.ndarray | None:
        """The error reaching ``layer``'s box (``mix`` (rows, cols, K) at ``origin``) when the carry is the
        layer before's with the same K: the part of the carried box it overlaps, zeros elsewhere; else None."""
        error = self.error
        if error is None or self.layer != layer - 1 or error.shape[2] != mix.shape[2]:
            return None
        incoming = np.zeros(mix.shape, dtype=np.float32)
        top, left = max(origin[0], self.origin[0]), max(origin[1], self.origin[1])
        bottom = min(origin[0] + mix.shape[0], self.origin[0] + error.shape[0])
        right = min(origin[1] + mix.shape[1], self.origin[1] + error.shape[1])
        if top < bottom and left < right:
            incoming[top - origin[0]:bottom - origin[0], left - origin[1]:right - origin[1]] = \
                error[top - self.origin[0]:bottom - self.origin[0], left - self.origin[1]:right - self.origin[1]]
        return incoming

    def keep(self, layer: int, origin: tuple[int, int], error: np.ndarray) -> None:
        """Hold ``layer``'s outgoing error (its box at ``origin``) for the next layer."""
        self.layer, self.origin, self.error = int(layer), (int(origin[0]), int(origin[1])), error


def fresh_error(mix: np.ndarray, layer: int, origin: tuple[int, int]) -> np.ndarray:
    """What stands in for the layer before's error where there is none (a run's first layer): :data:`LAYER_SHARE`
    of the error the blue-noise mask (at every one of its levels) would leave ((rows, cols, K) float32), so that
    such a layer starts from an error that varies from pixel to pixel and from layer to layer, as a carried one
    does, rather than from zero."""
    from heoslice.grading.halftone import BLUE_TILE, blue_noise_thresholds

    rows, cols = (np.arange(size) + start for size, start in zip(mix.shape[:2], origin))
    threshold = blue_noise_thresholds(layer).astype(np.float32)[np.ix_(rows % BLUE_TILE, cols % BLUE_TILE)]
    running = np.cumsum(mix, axis=2, dtype=np.float32)
    jetted = np.minimum((threshold[..., None] * running[..., -1:] >= running).sum(axis=2), mix.shape[2] - 1)
    taken = jetted[..., None] == np.arange(mix.shape[2])
    error = np.where(running[..., -1:] > 0, mix - taken, 0.0)
    return (np.float32(LAYER_SHARE) * error).astype(np.float32)


def _diffused(mix: np.ndarray, layer: int, carry: DiffusionCarry | None, origin: tuple[int, int],
              planes: np.ndarray, at: tuple[int, int]) -> np.ndarray:
    """Diffuse ``mix`` ((rows, cols, K) float32) of ``layer`` into ``planes`` at pixel ``at`` (row, col), the
    error from ``carry`` (the layer before's; None, or another layer's: :func:`fresh_error`) coming in, regions
    starting from the blue-noise halftone's choice (:data:`TOP_SHARE`), and this layer's error kept there."""
    from heoslice.grading.halftone import blue_noise_thresholds

    incoming = None if carry is None else carry.incoming(layer, origin, mix)
    if incoming is None:
        incoming = fresh_error(mix, layer, origin)
    # the layer's blue-noise thresholds, indexed by the planes' pixels (the box's pixel (0, 0) at ``at``)
    start = f32(np.roll(blue_noise_thresholds(layer), (at[0] - origin[0], at[1] - origin[1]), axis=(0, 1)))
    _diffuse(f32(mix), incoming, JARVIS_JUDICE_NINKE, np.array([LAYER_SHARE, TOP_SHARE], dtype=np.float32), start,
             int(layer) & 1, planes, int(at[0]), int(at[1]))
    if carry is not None:
        carry.keep(layer, origin, incoming)
    return planes


def diffuse_mix(mix: np.ndarray, layer: int, carry: DiffusionCarry | None = None,
                origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """The droplet masks ((K, rows, cols) bool) of a per-pixel mix ((rows, cols, K) float, rows summing to 1
    at solid pixels, 0 at empty ones) by error diffusion; the box's top-left pixel is ``origin`` of the
    layer (it places the carried error). ``carry``, when given, brings the layer before's error and takes
    this layer's."""
    mix = f32(mix)
    rows, cols, count = mix.shape
    planes = np.zeros((count, rows, -(-cols // 8)), dtype=np.uint8)
    _diffused(mix, layer, carry, origin, planes, (0, 0))
    return np.unpackbits(planes, axis=2, count=cols).view(bool)


def diffused_planes(layer: LabelledLayer, mixing: LayerMixes, base_channel: int, index: int,
                    planes: np.ndarray, carry: DiffusionCarry | None) -> np.ndarray:
    """The droplet masks of a labelled layer (``index``) by error diffusion, into ``planes`` ((K, h, ceil(w/8))
    uint8, zero): the label box's per-pixel mix (:func:`heoslice.grading.diffusion_kernels._pixel_mixes`)
    diffused, and every solid pixel outside the box on ``base_channel``."""
    label = layer.label
    rows = label.shape[0]
    if rows > 1 and label.strides[0] == 0:
        label = label[:1]
    origin = (int(layer.row0), int(layer.col0))
    mix = np.zeros((rows, label.shape[1], planes.shape[0]), dtype=np.float32)
    packed = np.ascontiguousarray(layer.packed)
    _pixel_mixes((np.ascontiguousarray(label), origin[0], origin[1], packed, rows),
                 (i64(mixing.family_of_label), f32(mixing.fraction), i64(mixing.layout), f32(mixing.mixes),
                  f32(mixing.target)), int(base_channel), mix)
    _diffused(mix, index, carry, origin, planes, origin)
    taken = np.bitwise_or.reduce(planes, axis=0)
    planes[base_channel] |= packed & ~taken
    return planes
