"""Error diffusion for K materials: each solid pixel takes the material nearest its mix plus the error that
reached it, and passes the difference on (the ``error-diffusion`` halftone of :mod:`.halftone`).

Vector error diffusion (Jarvis, Judice and Ninke's weights, serpentine rows) over the mix of K materials: the
material taken is the largest component of the corrected mix among those the pixel holds, so a region of
one material stays pure; error that reaches a pixel not holding its material (or off the solid) is
dropped, so a region's shares are kept without piling error up at its edges. A share :data:`LAYER_SHARE`
of each pixel's error goes to the same pixel of the next layer (:class:`DiffusionCarry`), so that a column
that took one material is pushed towards the others one layer up and columns do not line up from layer to
layer; the rest goes to the pixels after it in the layer. The error is carried from layer to layer within
one run of planes of a slice (consecutive layers rendered by one process,
:func:`heoslice.pipeline.runs.slice_run`) and starts afresh at a run's first layer, so a stack does not
depend on how many processes made it; a layer without the layer before's error starts from
:data:`LAYER_SHARE` of the error the blue-noise halftone would leave, and a region's first rows and sides
(where less error reaches a pixel) lean towards the blue-noise halftone's choice (:data:`TOP_SHARE`).
One compiled pass per layer over the solid pixels (:mod:`.diffusion_kernels`), a labelled layer's mix read
from a table of each label's mix (or made row by row where its families' cells differ).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.grading.diffusion_kernels import _diffuse, _diffuse_labelled
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
#: How far a pixel that less error reached than a region's inside (its first rows and sides) leans towards the
#: blue-noise halftone's choice, times the weight missing: without it a material of small share would start
#: only rows into its region.
TOP_SHARE = 1.0
#: The steady error of a material of share s inside a region of constant mix, as a multiple of 1/2 - s (two
#: materials; K: 1/2 - s - (K/2 - 1)/K): the diffusion of a constant s measured 0.41, 0.37, 0.32, 0.25 and 0.16
#: after each pixel for s = 2, 5, 10, 20 and 30 %, within 0.03 of 0.8 (1/2 - s). A region's first rows and sides
#: start from it (else a 5 % material starts rows into its region), and the error carried to the next layer is
#: taken less it (else the layers trade material where their mixes differ).
CHARGE = 0.8


@dataclass(slots=True)
class DiffusionCarry:
    """The error a layer's diffusion leaves to the next: its layer index, the top-left pixel (row, col) of the
    box it covers, and per pixel of the box the error per material ((rows, cols, K) float32; of two materials,
    the first's alone: (rows, cols, 1)). State handed
    from one layer to the next, not a cache: it changes what the next layer jets."""

    layer: int = -1
    origin: tuple[int, int] = (0, 0)
    error: np.ndarray | None = None

    def incoming(self, layer: int, channels: int) -> np.ndarray | None:
        """The error the layer before left ((rows, cols, n) float32 over its box at :attr:`origin`) when this
        carry is that layer's with ``channels`` (n) error channels; else None."""
        error = self.error
        if error is None or self.layer != layer - 1 or error.shape[2] != channels:
            return None
        return error

    def keep(self, layer: int, origin: tuple[int, int], error: np.ndarray) -> None:
        """Hold ``layer``'s outgoing error (its box at ``origin``) for the next layer."""
        self.layer, self.origin, self.error = int(layer), (int(origin[0]), int(origin[1])), error


def _settings(layer: int, at: tuple[int, int]) -> tuple:
    """The kernels' settings for ``layer``: the weights, (LAYER_SHARE, TOP_SHARE), the layer's blue-noise
    thresholds (at every one of the mask's levels) anchored at the layer's pixel (0, 0), rolled so that the
    kernel's pixel (0, 0) reads the layer's pixel ``at``, and the serpentine's flip."""
    from heoslice.grading.halftone import blue_noise_thresholds

    start = f32(np.roll(blue_noise_thresholds(layer), (-at[0], -at[1]), axis=(0, 1)))
    return JARVIS_JUDICE_NINKE, np.array([LAYER_SHARE, TOP_SHARE, CHARGE], dtype=np.float32), start, int(layer) & 1


def _state(layer: int, origin: tuple[int, int], shape: tuple[int, int, int], carry: DiffusionCarry | None) -> tuple:
    """The kernels' state for ``layer``'s box (``shape`` (rows, cols, K) at ``origin``): the layer before's error
    and this box's offset in it (or none, fresh), and the zero array this layer's error goes into."""
    carried = 1 if shape[2] == 2 else shape[2]  # two materials: the first's error (the other's is its negative)
    out = np.zeros((*shape[:2], carried), dtype=np.float32)
    error = None if carry is None else carry.incoming(layer, carried)
    if error is None:
        return np.zeros((0, 0, carried), dtype=np.float32), 0, 0, 1, out
    return (error, int(origin[0] - carry.origin[0]), int(origin[1] - carry.origin[1]), 0, out)


def diffuse_mix(mix: np.ndarray, layer: int, carry: DiffusionCarry | None = None,
                origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """The droplet masks ((K, rows, cols) bool) of a per-pixel mix ((rows, cols, K) float, rows summing to 1
    at solid pixels, 0 at empty ones) by error diffusion; the box's top-left pixel is ``origin`` of the
    layer (it places the carried error and the threshold mask). ``carry``, when given, brings the layer
    before's error and takes this layer's."""
    mix = f32(mix)
    rows, cols, count = mix.shape
    planes = np.zeros((count, rows, -(-cols // 8)), dtype=np.uint8)
    state = _state(layer, origin, mix.shape, carry)
    _diffuse(mix, (0, 0), state, _settings(layer, origin), planes)
    if carry is not None:
        carry.keep(layer, origin, state[-1])
    return np.unpackbits(planes, axis=2, count=cols).view(bool)


def diffused_planes(layer: LabelledLayer, mixing: LayerMixes, base_channel: int, index: int,
                    planes: np.ndarray, carry: DiffusionCarry | None) -> np.ndarray:
    """The droplet masks of a labelled layer (``index``) by error diffusion, into ``planes`` ((K, h, ceil(w/8))
    uint8, zero): the label box's mix read per label (or made row by row) and diffused in one compiled pass
    (:func:`heoslice.grading.diffusion_kernels._diffuse_labelled`), every solid pixel outside the box on
    ``base_channel``."""
    label = layer.label
    rows = label.shape[0]
    if rows > 1 and label.strides[0] == 0:
        label = label[:1]
    origin = (int(layer.row0), int(layer.col0))
    packed = np.ascontiguousarray(layer.packed)
    state = _state(index, origin, (rows, label.shape[1], planes.shape[0]), carry)
    _diffuse_labelled((np.ascontiguousarray(label), origin[0], origin[1], packed, rows),
                      (i64(mixing.family_of_label), f32(mixing.fraction), i64(mixing.layout), f32(mixing.mixes),
                       f32(mixing.target)), int(base_channel), state, _settings(index, (0, 0)), planes)
    if carry is not None:
        carry.keep(index, origin, state[-1])
    if origin != (0, 0) or rows != packed.shape[0] or label.shape[1] < packed.shape[1] * 8:
        taken = np.bitwise_or.reduce(planes, axis=0)
        planes[base_channel] |= packed & ~taken
    return planes
