"""The droplet masks of a graded layer: each solid pixel's mix halftoned into one material (:mod:`.halftone`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from heoslice.grading.cache import ChoiceTable, GradingCache
from heoslice.grading.droplets_kernels import (
    Dither,
    LabelledLayer,
    LayerMixes,
    agreed_choices,
    droplet_bits,
)
from heoslice.grading.halftone import DEFAULT_METHOD, TILE, check_method, layer_tile
from heoslice.grading.labels import LayerRegions, layer_regions
from heoslice.grading.materials import family_starts, target_fractions
from heoslice.grading.spec import GradeSpec, RegionSpec
from heoslice.layers.bits import count_solid
from heoslice.layers.rasterising import Grid
from heoslice.mesh.weld import distinct_rows

#: Most (distinct fraction, distinct cell mix) pairs whose choices :func:`_choice_table` tabulates for one
#: family: past it, a family of many sub-regions and varied cells rarely agrees, and is halftoned per pixel.
_TABLE_SHARES = 1 << 16


def droplet_planes(points: np.ndarray, offsets: np.ndarray, area: np.ndarray, parent: np.ndarray,
                   loop_shell: np.ndarray | None, mask: np.ndarray | None, grid: Grid, spec: GradeSpec, layer: int, *,
                   point_material: np.ndarray | None = None, packed: np.ndarray | None = None,
                   cache: GradingCache | None = None, method: str = DEFAULT_METHOD, carry=None) -> np.ndarray:
    """The droplet masks of one graded layer, bit-packed: (K, height, ceil(width / 8)) uint8, rows MSB first.

    Each solid pixel's mix is its family's start mix at its lattice cell moved by its
    sub-region's fraction towards the target (eq. 1), halftoned by ``method`` (:mod:`heoslice.grading.halftone`;
    ordered and blue noise in its float32 arithmetic, error diffusion with the layer before's error from
    ``carry``, a :class:`heoslice.grading.diffusion.DiffusionCarry`), in one compiled pass over the
    layer's pixels, without the RGBA image: the path of every multi-material slice (and of
    ``render_graded(..., channels=True)``). Solid pixels outside every family jet the base
    material. Arguments as :func:`render_graded`; mask (h, w) bool, ``packed`` the same mask
    bit-packed (:func:`heoslice.layers.rasterising.packed_mask`) when the caller has it; with it, the
    mask may be None (no per-pixel mask built or read: :func:`layer_regions`); ``cache`` as there.
    """
    packed = np.packbits(mask, axis=1) if packed is None else packed
    regions = layer_regions(points, offsets, area, parent, mask, grid, _layout_spec(spec), packed, cache)
    return labelled_droplet_planes(regions, spec, loop_shell, point_material, packed, grid, layer, cache, method, carry)


def droplet_counts(planes: np.ndarray, solid: int) -> list[int]:
    """Solid pixels in each droplet mask of a layer ((K, h, ceil(w / 8)) packed, :func:`droplet_planes`) of
    ``solid`` solid pixels: every solid pixel jets one material, so the last mask holds those the others do
    not (one pass over the masks fewer)."""
    counts = [count_solid(plane) for plane in planes[:-1]]
    return counts + [solid - sum(counts)]


def _layout_spec(spec: GradeSpec) -> RegionSpec:
    """The sub-region layout the masks need: without a gradient every sub-region of a family jets its
    start mix, so one sub-region per family (N_R = 1) gives the same masks, without the per-pixel
    sub-region index (the cells' nearest contour points, which the start mix reads, are the same)."""
    if spec.function is None:
        return replace(spec.regions, count=1)
    return spec.regions


def labelled_droplet_planes(regions: LayerRegions, spec: GradeSpec, loop_shell, point_material, packed: np.ndarray,
                            grid: Grid, layer: int, cache: GradingCache | None = None, method: str = DEFAULT_METHOD,
                            carry=None) -> np.ndarray:
    """:func:`droplet_planes` of a layer whose sub-regions are already known; ``cache`` keeps the
    choice table for the next layer (:func:`_layer_choice_table`)."""
    diffused = check_method(method) == "error-diffusion"
    tile = layer_tile(layer, "ordered" if diffused else method)
    materials = spec.channel_materials()
    planes = np.zeros((len(materials), grid.height, -(-grid.width // 8)), dtype=np.uint8)
    base_channel = spec.channel_index(spec.base)
    if not regions.fields:
        return droplet_bits(LabelledLayer(np.zeros((0, 0), np.uint8), 0, 0, packed),
                            LayerMixes(np.zeros(1, np.int64), np.zeros(1), np.zeros((0, 5), np.int64), np.zeros(0),
                                       np.zeros(len(materials))),
                            Dither(tile, np.full((1, TILE * TILE), base_channel, np.int8), base_channel), planes)
    target_mix = np.zeros(len(materials))
    if spec.target is not None and spec.function is not None:
        target_mix[spec.channel_index(spec.target)] = 1.0
    fractions = target_fractions(regions, spec)
    moved = fractions.astype(np.float32)

    def as_one(number: int, low: np.ndarray, high: np.ndarray) -> bool:
        return not diffused and jets_as_one(low, high, moved[regions.base[number]:regions.base[number + 1]],
                                            target_mix)

    mixes = family_starts(regions, spec, loop_shell, point_material, as_one)
    family_of_label = np.zeros(regions.label_count, dtype=np.int64)
    for number in range(len(regions.fields)):
        family_of_label[regions.base[number]:regions.base[number + 1]] = number
    sizes = np.array([mix.size for mix in mixes])
    layout = np.array([(field.box[0], field.box[2], field.lattice.cell, field.lattice.cols, start)
                       for field, start in zip(regions.fields, np.cumsum(sizes) - sizes)], dtype=np.int64)
    # in the kernel's float32 at once: one copy of the cells' mixes, not a float64 one and then its cast
    flat_mixes = np.concatenate([mix.ravel() for mix in mixes], dtype=np.float32)
    mixing = LayerMixes(family_of_label, fractions, layout, flat_mixes, target_mix)
    labelled = LabelledLayer(regions.label, *regions.box[::2], packed)
    if diffused:
        from heoslice.grading.diffusion import diffused_planes  # its kernels load with the method that needs them

        return diffused_planes(labelled, mixing, base_channel, layer, planes, carry)
    table = _layer_choice_table(regions, mixes, fractions, target_mix, base_channel, cache)
    return droplet_bits(labelled, mixing, Dither(tile, table, base_channel), planes)


def jets_as_one(low: np.ndarray, high: np.ndarray, moved: np.ndarray, target: np.ndarray,
                levels: int = TILE * TILE) -> bool:
    """Whether every start mix between ``low`` and ``high`` ((K,) float each, per channel, in [0, 1]), moved
    by each fraction of ``moved`` ((l,) float32, in [0, 1]; False for any other) towards ``target`` ((K,),
    eq. 1), jets the same channel at every dither level: the halftone's comparisons
    (:func:`heoslice.grading.droplets_kernels.droplet_bits`) are then decided alike for all of them, with a
    margin for its float32 rounding.

    A moved mix's running sums and total grow with each channel of the start mix, so over the box they lie
    between those of its lowest and highest corners; a level t jets channel m's condition (running sum above
    t times the total) alike throughout when it holds at the worst of them, or fails at the best: it is
    undecided only for t from (lowest sum - margin) / highest total to (highest sum + margin) / lowest total,
    and the ``levels`` levels are (i + 1/2) / levels.
    """
    f = np.asarray(moved, dtype=np.float64)[:, None]
    sums_low = np.cumsum(low + f * (target - low), axis=1)  # (l, K): the running sums, the total last
    sums_high = np.cumsum(high + f * (target - high), axis=1)
    channels, count = sums_low.shape[1], levels
    total_low, total_high = sums_low[:, -1:], sums_high[:, -1:]
    # a few roundings of float32 (2^-24 each) per channel on sums of up to K shares, with room to spare
    margin = (6 * channels + 4) * channels * max(1.0, float(total_high.max(initial=0.0))) * 2.0 ** -23
    if not (np.isfinite(total_high).all() and (total_low > margin).all() and ((f >= 0.0) & (f <= 1.0)).all()):
        return False
    # the first and last undecided level, of 0 .. count - 1
    first = np.maximum(np.ceil((sums_low[:, :-1] - margin) / total_high * count - 0.5), 0.0)
    last = np.minimum(np.floor((sums_high[:, :-1] + margin) / total_low * count - 0.5), count - 1.0)
    return bool((first > last).all())


def _layer_choice_table(regions: LayerRegions, mixes: list[np.ndarray], fractions: np.ndarray,
                        target_mix: np.ndarray, base_channel: int, cache: GradingCache | None,
                        levels: int = TILE * TILE) -> np.ndarray:
    """:func:`_choice_table` with label 0 (solid pixels outside every family) on the base channel; the
    last layer's (kept in ``cache``) when its label bases, fractions, mixes and base channel are the same
    (an extruded part)."""
    key = (np.array([base_channel, levels]), regions.base, fractions, target_mix, *mixes)
    if cache is not None and cache.choices is not None and cache.choices.matches(key):
        return cache.choices.table
    table = _choice_table(regions, mixes, fractions, target_mix, levels)
    table[0] = base_channel
    if cache is not None:
        cache.choices = ChoiceTable(key, table)
    return table


def _choice_table(regions: LayerRegions, mixes: list[np.ndarray], fractions: np.ndarray,
                  target_mix: np.ndarray, levels: int = TILE * TILE) -> np.ndarray:
    """The channel each label jets at each of the ``levels`` dither thresholds ((labels, levels) int8), where every
    lattice cell of the label's family agrees on it (-1 where they do not: those pixels are halftoned
    per pixel). Computed in the kernel's float32 arithmetic (compiled,
    :func:`heoslice.grading.droplets_kernels.agreed_choices`), so a pixel's channel is the same either way;
    it turns the per-pixel mix into one table look-up, also for a family whose start mix varies only in
    rounding (a contour material that is level over a layer)."""
    count = levels
    table = np.full((regions.label_count, count), -1, dtype=np.int8)
    levels = ((np.arange(count) + 0.5) / count).astype(np.float32)
    for number, mix in enumerate(mixes):
        flat = mix.reshape(-1, mix.shape[-1]).astype(np.float32)
        labels = np.arange(regions.base[number], regions.base[number + 1])
        moved, of_label = np.unique(fractions.astype(np.float32)[labels], return_inverse=True)
        if len(flat) and (flat == flat[0]).all():
            cells = flat[:1]  # one start mix (a contour of one material, jets_as_one)
        else:
            cells = flat[distinct_rows(flat)[1]] if len(flat) else flat  # by their bits
        if len(cells) * len(moved) <= _TABLE_SHARES:
            table[labels] = agreed_choices(cells, moved, target_mix, levels)[of_label]
    return table
