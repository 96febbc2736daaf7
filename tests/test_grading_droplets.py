"""Tests of heoslice.grading.droplets: the choice table over families whose cells agree, and the
one-sub-region layout of masks without a gradient."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading import GradeSpec, RegionSpec, layer_regions
from heoslice.grading.droplets import (
    _choice_table,
    droplet_counts,
    droplet_planes,
    jets_as_one,
    labelled_droplet_planes,
)
from heoslice.grading.halftone import TILE
from heoslice.layers.bits import count_solid
from heoslice.layers.rasterising import Grid, packed_mask
from heoslice.material import DEFAULT_MATERIALS, Material, make_function

PX = 25.4 / 600
LEVELS = ((np.arange(TILE * TILE) + 0.5) / (TILE * TILE)).astype(np.float32)


def square_tube(outer: float, inner: float):
    """points, offsets, signed areas and parents of a square tube about the origin (half-sides, mm), and a
    600 dpi grid over it."""
    ring = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    points = np.concatenate([outer * ring, inner * ring[::-1]])
    size = int(np.ceil(2 * (outer + 0.5) / PX))
    grid = Grid(width=size, height=size, x_left=-outer - 0.5, y_top=outer + 0.5, px=PX, py=PX)
    return points, np.array([0, 4, 8]), np.array([4 * outer**2, -4 * inner**2]), np.array([-1, 0]), grid


def brute_choice(mix: np.ndarray, fraction: float, target: np.ndarray) -> np.ndarray:
    """(256,) the channel one pixel of this start mix and fraction jets at each threshold level, written
    as the kernel's per-pixel loop (float32, running sum)."""
    share = mix.astype(np.float32) + np.float32(fraction) * (target.astype(np.float32) - mix.astype(np.float32))
    total = np.float32(0.0)
    for value in share:
        total += value
    out = np.empty(len(LEVELS), dtype=np.int8)
    for number, level in enumerate(LEVELS):
        t = level * (total if total > 0 else np.float32(1.0))
        pick, running = len(share) - 1, np.float32(0.0)
        for channel in range(len(share) - 1):
            running += share[channel]
            if t < running:
                pick = channel
                break
        out[number] = pick
    return out


@pytest.mark.parametrize("spread", [1e-7, 0.3])
def test_choice_table_entries_are_every_cells_choice_where_the_cells_agree(spread):
    """Each entry of the choice table is the per-pixel choice of every cell of the label's family where
    they all agree on it, and -1 exactly where they do not; a family whose cells differ only in rounding
    (spread 1e-7) has no -1 entry at all, one whose cells differ widely (0.3) has some."""
    rng = np.random.default_rng(5)
    m = 0.4 + spread * rng.uniform(-1, 1, (6, 7))
    mixes = [np.stack([1 - m, m], axis=-1), np.tile([0.25, 0.75], (2, 3, 1))]
    base = np.array([1, 5, 8])
    fractions = np.r_[0.0, rng.uniform(0, 1, 4), 0.0, 0.5, 0.5]
    target = np.array([0.0, 1.0])
    table = _choice_table(SimpleNamespace(base=base, label_count=int(base[-1])), mixes, fractions, target)
    for number, mix in enumerate(mixes):
        for label in range(base[number], base[number + 1]):
            choices = np.array([brute_choice(cell, fractions[label], target) for cell in mix.reshape(-1, 2)])
            agreed = (choices == choices[0]).all(axis=0)
            assert np.array_equal(table[label], np.where(agreed, choices[0], -1))
    assert (table[1:5] < 0).any() == (spread > 1e-3)
    assert (table[5:] >= 0).all()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 4), st.sampled_from([0.0, 1e-7, 0.02, 0.5]))
def test_choice_table_is_the_brute_force_agreement_for_any_number_of_channels(seed, channels, spread):
    """For mixes of 2 to 4 channels near one mix (or equal, or far apart), fractions of one family, and a
    target of one channel, each table entry is the cells' common per-pixel choice where they agree, else -1."""
    rng = np.random.default_rng(seed)
    centre = rng.dirichlet(np.ones(channels))
    cells = np.clip(centre + spread * rng.uniform(-1, 1, (int(rng.integers(1, 40)), channels)), 0.0, None)
    cells[cells.sum(axis=1) == 0] = centre  # a mix of no material is no mix
    cells /= cells.sum(axis=1, keepdims=True)
    target = np.eye(channels)[int(rng.integers(channels))]
    fractions = np.r_[0.0, rng.uniform(0, 1, 3)]
    base = np.array([1, 4])
    table = _choice_table(SimpleNamespace(base=base, label_count=4), [cells.reshape(1, -1, channels)], fractions,
                          target)
    for label in range(1, 4):
        choices = np.array([brute_choice(cell, fractions[label], target) for cell in cells])
        agreed = (choices == choices[0]).all(axis=0)
        assert np.array_equal(table[label], np.where(agreed, choices[0], -1))


def box_near_a_level(rng: np.random.Generator, channels: int, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of a box of start mixes ((K,) each, in [0, 1]) about a random mix, ``spread`` wide per
    channel; half the time the mix's first running sum sits within a few float32 roundings of a dither level,
    where rounding decides."""
    centre = rng.dirichlet(np.ones(channels))
    if rng.random() < 0.5:
        level = float(LEVELS[rng.integers(len(LEVELS))])
        moved = level + rng.choice([-1.0, 1.0]) * rng.choice([0.0, 1e-9, 3e-8, 1e-7, 1e-6])
        centre[0], centre[1] = moved, centre[0] + centre[1] - moved
        centre = np.clip(centre, 0.0, 1.0)
    offsets = spread * rng.uniform(0.0, 1.0, (2, channels))
    return np.clip(centre - offsets[0], 0.0, 1.0), np.clip(centre + offsets[1], 0.0, 1.0)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 4), st.sampled_from([0.0, 1e-9, 6e-8, 1e-6, 1e-3, 0.05]),
       st.booleans())
def test_a_box_of_mixes_taken_as_one_jets_alike_at_every_mix_in_it(seed, channels, spread, graded):
    """Where jets_as_one takes a box of start mixes as one, every mix in it (each corner, and random mixes
    inside, as float64 before the kernel's float32) jets the same channel at every dither level for every
    fraction asked about, as the kernel's per-pixel loop (brute_choice) makes them: so one of them may stand
    for a family's cells without changing a pixel."""
    rng = np.random.default_rng(seed)
    low, high = box_near_a_level(rng, channels, spread)
    target = np.zeros(channels)
    moved = np.zeros(1, dtype=np.float32)
    if graded:
        target[rng.integers(channels)] = 1.0
        moved = np.unique(rng.uniform(0.0, 1.0, rng.integers(1, 4)).astype(np.float32))
    if not jets_as_one(low, high, moved, target):
        return
    corners = np.array(np.meshgrid(*zip(low, high), indexing="ij")).reshape(channels, -1).T
    inside = low + rng.uniform(0.0, 1.0, (20, channels)) * (high - low)
    for fraction in moved:
        expected = brute_choice(low, fraction, target)
        for mix in np.concatenate([corners, inside]):
            assert np.array_equal(brute_choice(mix, fraction, target), expected)


def test_mixes_that_differ_in_rounding_are_taken_as_one_and_mixes_across_a_level_are_not():
    """jets_as_one takes nearly every box that is float32 rounding wide (a gradient along z through a
    layer, whose contour points differ in their last bits) as one, and never one whose mixes jet differently
    at some level: two mixes either side of a level, a box across many levels, a mix of no material."""
    rng = np.random.default_rng(11)
    taken = []
    for _ in range(400):
        channels = int(rng.integers(2, 5))
        centre = rng.dirichlet(np.ones(channels))
        target = np.eye(channels)[rng.integers(channels)]
        moved = np.unique(rng.uniform(0.0, 1.0, 3).astype(np.float32))
        taken.append(jets_as_one(centre - 6e-8, centre + 6e-8, moved, target))
    assert np.mean(taken) > 0.97
    level = float(LEVELS[128])
    low, high = np.array([level - 1e-7, 1 - level]), np.array([level + 1e-7, 1 - level])
    zero = np.zeros(1, dtype=np.float32)
    assert not np.array_equal(brute_choice(low, 0.0, np.zeros(2)), brute_choice(high, 0.0, np.zeros(2)))
    assert not jets_as_one(low, high, zero, np.zeros(2))
    assert not jets_as_one(np.array([0.2, 0.2]), np.array([0.7, 0.7]), zero, np.zeros(2))
    assert not jets_as_one(np.zeros(2), np.zeros(2), zero, np.zeros(2))
    assert not jets_as_one(np.array([0.4, 0.6]), np.array([0.4, 0.6]), np.array([1.5], np.float32), np.eye(2)[1])


def test_mixes_on_one_side_of_a_level_that_float32_puts_on_both_are_not_taken_as_one():
    """The margin for float32: two mixes whose first share lies above a level in exact arithmetic (by 1e-9
    and 4e-8, totals 1 and just below) round to the level itself and to one step above it, and so jet
    different materials there; jets_as_one does not take their box as one (without its margin it would)."""
    level = float(LEVELS[128])
    low, high = np.array([level + 1e-9, 1 - level - 4e-8]), np.array([level + 4e-8, 1 - level - 4e-8])
    assert low[0] > level * low.sum() and high[0] > level * high.sum()
    assert brute_choice(low, 0.0, np.zeros(2))[128] != brute_choice(high, 0.0, np.zeros(2))[128]
    assert not jets_as_one(low, high, np.zeros(1, dtype=np.float32), np.zeros(2))


def test_masks_without_a_gradient_are_those_of_the_full_sub_region_layout():
    """Without a distribution function, droplet_planes (one sub-region per family) gives the masks of the
    layer labelled with eq. 8's full sub-region layout, with a contour material that varies along the
    rings (per-pixel mixes) and one level to rounding (the table)."""
    points, offsets, area, parent, grid = square_tube(6.0, 2.0)
    packed = packed_mask(points, offsets, grid)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.2), None, None, None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    for material in (np.linspace(0.1, 0.9, len(points)), np.full(len(points), 0.3) + 1e-9 * np.arange(len(points))):
        full = layer_regions(points, offsets, area, parent, None, grid, spec.regions, packed)
        assert full.label_count > 10
        expected = labelled_droplet_planes(full, spec, None, material, packed, grid, 3)
        got = droplet_planes(points, offsets, area, parent, None, None, grid, spec, 3, point_material=material,
                             packed=packed)
        assert np.array_equal(got, expected)
        assert got.any()


@pytest.mark.parametrize("target, channels", [("M2", 2), ("green", 3)])
def test_every_solid_pixel_is_in_one_droplet_mask_so_the_counts_are_the_masks_bits(target, channels):
    """The droplet masks of a graded square tube (towards M2: two materials; towards a third) partition its
    solid pixels: no pixel in two masks, none in none; so droplet_counts, which takes the last mask's count as
    the solid count less the others', gives each mask's own number of bits."""
    points, offsets, area, parent, grid = square_tube(6.0, 2.0)
    packed = packed_mask(points, offsets, grid)
    material = DEFAULT_MATERIALS["M2"] if target == "M2" else Material("green", (0, 255, 0))
    spec = GradeSpec(RegionSpec(nozzle_mm=0.2), make_function("linear"), material, None, DEFAULT_MATERIALS["M1"],
                     DEFAULT_MATERIALS["M2"])
    planes = droplet_planes(points, offsets, area, parent, None, None, grid, spec, 3, packed=packed)
    assert len(planes) == channels
    counts = [count_solid(plane) for plane in planes]
    assert np.array_equal(np.bitwise_or.reduce(planes, axis=0), packed) and sum(counts) == count_solid(packed)
    assert droplet_counts(planes, count_solid(packed)) == counts and sum(count > 0 for count in counts) >= 2
