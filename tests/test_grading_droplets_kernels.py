"""Tests of heoslice.grading.droplets_kernels: droplet_bits against np.packbits of the brute-force per-pixel
choice (the table entry at the pixel's dither level, choose_materials of its eq. 1 mix where that is -1, the
base channel outside the labels) for any number of channels, label boxes, dither tiles and broadcast labels,
the bytes it leaves alone, and one compiled signature for every layer's tile."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from heoslice.grading.field import LABEL_TYPES


def halftone_bits(label, origin, packed, family_of_label, fraction, layout, mixes, target, tile, base_channel, planes,
                  table):
    """droplet_bits of the given arrays, grouped as it takes them."""
    from heoslice.grading.droplets_kernels import (
        Dither,
        LabelledLayer,
        LayerMixes,
        droplet_bits,
    )

    mixing = LayerMixes(family_of_label, fraction, layout, mixes, target)
    return droplet_bits(LabelledLayer(label, *origin, packed), mixing, Dither(tile, table, base_channel), planes)


def random_halftone_case(rng, channels: int, height: int, width: int, label_dtype):
    """A random droplet_bits input: solid pixels in runs, a label box that covers only part of them (offset,
    clipped), a few families of random per-cell start mixes, and a choice table whose entries are a
    random channel or -1 (per pixel mix) per label and level, row 0 the base channel."""
    solid = np.repeat(rng.random((height, -(-width // 3))) < 0.7, 3, axis=1)[:, :width]
    r0, c0 = int(rng.integers(0, height)), int(rng.integers(0, width))
    rows, cols = int(rng.integers(0, height - r0 + 1)), int(rng.integers(0, width - c0 + 1))
    # a few labels, or up to 256 (labels past 127 in uint8)
    families = int(rng.integers(1, 4))
    per_family = int(rng.integers(1, 6) if rng.random() < 0.5 else rng.integers(40, 86))
    count = 1 + families * per_family
    label = np.repeat(rng.integers(0, count, (rows, -(-cols // 4))), 4, axis=1)[:, :cols].astype(label_dtype)
    family_of_label = np.concatenate([[0], np.repeat(np.arange(families), per_family)]).astype(np.int64)
    layout, mixes = [], []
    for _ in range(families):
        cell = int(rng.integers(1, 9))
        grid_rows, grid_cols = -(-max(rows, 1) // cell), -(-max(cols, 1) // cell)
        mix = rng.random((grid_rows * grid_cols, channels)) * (rng.random((grid_rows * grid_cols, channels)) < 0.8)
        layout.append((r0, c0, cell, grid_cols, sum(m.size for m in mixes)))
        mixes.append(mix.ravel())
    base = int(rng.integers(0, channels))
    table = rng.integers(0, channels, (count, 256)).astype(np.int8)
    per_pixel = rng.random(count) < 0.4
    table[per_pixel] = -1
    table[rng.random((count, 256)) < 0.1] = -1
    table[0] = base
    return dict(solid=solid, label=label, origin=(r0, c0), family_of_label=family_of_label,
                fraction=rng.random(count).astype(np.float32), layout=np.array(layout, dtype=np.int64),
                mixes=np.concatenate(mixes).astype(np.float32),
                target=np.eye(channels, dtype=np.float32)[int(rng.integers(0, channels))], base=base, table=table)


def assert_droplet_bits_are_the_per_pixel_choice(rng, case: dict, channels: int, tile: np.ndarray, level: np.ndarray,
                                                 layer: int) -> None:
    """droplet_bits on ``case`` equals np.packbits of the brute-force per-pixel choice (the table entry at the
    pixel's dither ``level``, choose_materials of its eq. 1 mix where that is -1, the base channel outside
    the labels and on label 0), and it leaves every byte without a solid pixel as it was."""
    from helpers import choose_materials

    solid, label, (r0, c0), table = case["solid"], case["label"], case["origin"], case["table"]
    size = level.shape[0]
    rows, cols = label.shape
    r, c = np.indices(solid.shape)
    inside = (r >= r0) & (r < r0 + rows) & (c >= c0) & (c < c0 + cols)
    number = np.zeros(solid.shape, dtype=np.int64)
    number[inside] = label[r[inside] - r0, c[inside] - c0]
    entry = table[number, level[r % size, c % size]].astype(np.int64)
    family = case["family_of_label"][number]
    cell_row, cell_col, cell, per_row, start = np.moveaxis(case["layout"][family], -1, 0)
    first = start + (((r - cell_row) // cell) * per_row + (c - cell_col) // cell) * channels
    start_mix = case["mixes"][np.where(inside & (entry < 0), first, 0)[None] + np.arange(channels)[:, None, None]]
    f = case["fraction"][number][None]
    mix = start_mix + f * (case["target"][:, None, None] - start_mix)
    chosen = np.where(inside & (entry >= 0), entry, case["base"])
    chosen = np.where(inside & (entry < 0), choose_materials(mix, solid, layer), chosen)
    expected = np.packbits((chosen[None] == np.arange(channels)[:, None, None]) & solid[None], axis=2)

    args = (label, (r0, c0), np.packbits(solid, axis=1), case["family_of_label"], case["fraction"], case["layout"],
            case["mixes"], case["target"], tile, case["base"])
    assert np.array_equal(halftone_bits(*args, np.zeros_like(expected), table), expected)
    junk = rng.integers(0, 256, expected.shape, dtype=np.uint8)
    got = halftone_bits(*args, junk.copy(), table)
    written = np.packbits(solid, axis=1).astype(bool)[None].repeat(channels, axis=0)
    assert np.array_equal(got[written], expected[written])
    assert np.array_equal(got[~written], junk[~written])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2, 3, 4, 5, 9]), st.integers(1, 40), st.integers(1, 70),
       st.sampled_from(LABEL_TYPES))
def test_droplet_bits_is_the_per_pixel_choice_packed(seed, channels, height, width, label_dtype):
    """droplet_bits equals np.packbits of the brute-force per-pixel choice: outside the label box and on
    label 0 the base channel, else the table entry at the pixel's dither level, else (entry -1)
    choose_materials of the pixel's eq. 1 mix; for any number of channels (one to nine, over one
    pattern word or several), widths not a multiple of 8 or 16, label boxes covering part of the solid;
    and it writes only the bytes that hold a solid pixel."""
    from heoslice.grading.halftone import layer_tile

    rng = np.random.default_rng(seed)
    case = random_halftone_case(rng, channels, height, width, label_dtype)
    layer = int(rng.integers(0, 1000))
    tile = layer_tile(layer)
    level = np.rint(tile * 256 - 0.5).astype(np.int64)
    assert_droplet_bits_are_the_per_pixel_choice(rng, case, channels, tile, level, layer)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2, 3, 4]), st.integers(1, 30), st.integers(40, 200))
def test_droplet_bits_of_one_label_everywhere_is_the_per_pixel_choice(seed, channels, height, width):
    """One label at every pixel of the box (a coloured layer of one family), its table entries nearly all
    set: the chunks taken as that label's whole pattern word give the brute-force per-pixel choice."""
    from heoslice.grading.halftone import layer_tile

    rng = np.random.default_rng(seed)
    for _ in range(50):  # a box of whole chunks, drawn again rather than filtered (hypothesis's health check)
        case = random_halftone_case(rng, channels, height, width, np.uint16)
        rows, cols = case["label"].shape
        if rows > 0 and cols >= 32:
            break
    assume(rows > 0 and cols >= 32)
    value = int(rng.integers(1, len(case["table"])))
    case["table"][value] = rng.integers(0, channels, 256)
    case["table"][value, rng.random(256) < 0.02] = -1
    case["label"] = np.broadcast_to(np.uint16(value), (rows, cols))
    layer = int(rng.integers(0, 1000))
    tile = layer_tile(layer)
    assert_droplet_bits_are_the_per_pixel_choice(rng, case, channels, tile, np.rint(tile * 256 - 0.5).astype(np.int64),
                                                 layer)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2, 3, 5]), st.integers(2, 30), st.integers(1, 70))
def test_droplet_bits_reads_labels_broadcast_down_their_box_as_their_copy(seed, channels, height, width):
    """Labels that are one value, or one row, seen at every row of the box (a layer of one family of one
    sub-region: no array of the box) make the same masks as the same labels written out row by row."""
    from heoslice.grading.halftone import layer_tile

    rng = np.random.default_rng(seed)
    for _ in range(50):  # a box of two rows or more, drawn again rather than filtered (hypothesis's health check)
        case = random_halftone_case(rng, channels, height, width, np.uint16)
        rows, cols = case["label"].shape
        if rows > 1 and cols > 0:
            break
    assume(rows > 1 and cols > 0)
    tile = layer_tile(int(rng.integers(0, 1000)))
    args = (np.packbits(case["solid"], axis=1), case["family_of_label"], case["fraction"], case["layout"],
            case["mixes"], case["target"], tile, case["base"])
    value = np.uint16(rng.integers(0, len(case["table"])))
    for label in (np.broadcast_to(value, (rows, cols)), np.broadcast_to(case["label"][:1], (rows, cols))):
        assert label.strides[0] == 0
        planes = np.zeros((channels, height, -(-width // 8)), np.uint8)
        expected = halftone_bits(label.copy(), case["origin"], *args, planes.copy(), case["table"])
        assert np.array_equal(halftone_bits(label, case["origin"], *args, planes, case["table"]), expected)


@pytest.mark.parametrize("size", [1, 2, 4, 8, 16, 32, 64])
def test_droplet_bits_follows_a_dither_tile_of_any_size(size):
    """With an ordered-dither tile of any power-of-two size n (smaller than the 16-pixel pattern block,
    or larger: several blocks per tile row), each labelled pixel jets table[label, level] at its level
    bayer[row % n, col % n] (levels (k + 1/2) / n^2), exactly as a per-pixel look-up."""
    from heoslice.grading.halftone import bayer_matrix

    rng = np.random.default_rng(size)
    channels, height, width = 3, 70, 133
    solid = rng.random((height, width)) < 0.9
    label = rng.integers(0, 20, (height - 5, width - 9)).astype(np.uint16)
    table = rng.integers(0, channels, (20, size * size)).astype(np.int8)
    table[0] = 1
    bayer = bayer_matrix(size)
    r, c = np.indices(solid.shape)
    number = np.zeros(solid.shape, dtype=np.int64)
    number[2:2 + label.shape[0], 7:7 + label.shape[1]] = label
    chosen = table[number, bayer[r % size, c % size]]
    expected = np.packbits((chosen[None] == np.arange(channels)[:, None, None]) & solid[None], axis=2)
    planes = np.zeros_like(expected)
    got = halftone_bits(label, (2, 7), np.packbits(solid, axis=1), np.zeros(20, np.int64), np.zeros(20),
                       np.zeros((1, 5), np.int64), np.zeros(channels), np.zeros(channels),
                       (bayer + 0.5) / (size * size), 1, planes, table)
    assert np.array_equal(got, expected)


def test_droplet_bits_takes_every_layers_tile_through_one_compiled_signature():
    """Tiles of any layout (a layer's, and one transposed: Fortran-ordered) reach the kernel as the same
    C-ordered argument types: the compiled kernel (which checks its arguments in the tests) takes them all;
    compiled just in time, numba makes one version, not one per layout."""
    from heoslice.grading.droplets_kernels import _droplet_bits
    from heoslice.grading.halftone import layer_tile
    from heoslice.jit import CHECK_VARIABLE, compiled_module

    label = np.ones((4, 16), np.uint16)
    table = np.ones((2, 256), np.int8)
    tiles = [layer_tile(layer) for layer in range(4)] + [layer_tile(5).T]
    for tile in tiles:
        halftone_bits(label, (0, 0), np.full((4, 2), 255, np.uint8), np.zeros(2, np.int64), np.zeros(2),
                     np.zeros((1, 5), np.int64), np.zeros(2), np.zeros(2), tile, 0,
                     np.zeros((2, 4, 2), np.uint8), table)
    assert {tile.flags.c_contiguous for tile in tiles} == {True, False}
    if compiled_module() is not None:
        assert os.environ.get(CHECK_VARIABLE) == "1"  # so each call above checked its arrays were C-ordered
    else:
        layouts = {array.layout for signature in _droplet_bits.overloads for array in signature[2].types[:3]}
        assert layouts == {"C"}


def wide_halftone_case(rng, channels: int, missing: str, entries: int):
    """A droplet_bits input with rows of many 16-pixel chunks inside the labels: label bands of 1-12 pixels,
    solid pixels with empty stretches (whole empty bytes and chunks), the label box a little inside the
    solid; the table ((labels, entries) int8) has no -1 ('none'), all -1 for one family's labels as a
    family of per-cell mixes gets ('labels'), or -1 at scattered entries ('entries')."""
    height, width = 12, 16 * 23 + 5
    solid = rng.random((height, width)) < 0.95
    for start in rng.integers(0, width, 6):
        solid[:, start:start + int(rng.integers(8, 40))] = False
    r0, c0 = int(rng.integers(0, 3)), int(rng.integers(0, 20))
    rows, cols = height - r0 - int(rng.integers(0, 3)), width - c0 - int(rng.integers(0, 20))
    families, per_family = 3, 4
    count = 1 + families * per_family
    runs = rng.integers(1, 13, cols)
    label = np.repeat(rng.integers(0, count, (rows, cols)), runs, axis=1)[:, :cols].astype(np.uint16)
    family_of_label = np.concatenate([[0], np.repeat(np.arange(families), per_family)]).astype(np.int64)
    layout, mixes = [], []
    for _ in range(families):
        cell = int(rng.integers(1, 9))
        grid_rows, grid_cols = -(-rows // cell), -(-cols // cell)
        layout.append((r0, c0, cell, grid_cols, sum(m.size for m in mixes)))
        mixes.append(rng.random(grid_rows * grid_cols * channels))
    base = int(rng.integers(0, channels))
    table = rng.integers(0, channels, (count, entries)).astype(np.int8)
    if missing == "labels":
        table[family_of_label == int(rng.integers(0, families))] = -1
    elif missing == "entries":
        table[rng.random((count, entries)) < 0.02] = -1
    table[0] = base
    return dict(solid=solid, label=label, origin=(r0, c0), family_of_label=family_of_label,
                fraction=rng.random(count).astype(np.float32), layout=np.array(layout, dtype=np.int64),
                mixes=np.concatenate(mixes).astype(np.float32),
                target=np.eye(channels, dtype=np.float32)[int(rng.integers(0, channels))], base=base, table=table)


@pytest.mark.parametrize("channels", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("size", [4, 16, 32])
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), missing=st.sampled_from(["none", "labels", "entries"]))
def test_droplet_bits_is_the_per_pixel_choice_along_wide_rows(channels, size, seed, missing):
    """Along rows of many 16-pixel chunks inside the labels, droplet_bits is the brute-force per-pixel choice
    (the table entry at the pixel's level of the n x n dither tile, choose_materials of the eq. 1 mix
    where it is -1, the base channel outside the labels) for one to five channels (two, the last
    plane the solid less the first; up to four, one pattern word), whether no label lacks an entry,
    a whole family does (stretches of per-pixel mixes between table look-ups) or scattered entries
    do (with the 16 x 16 tile of choose_materials; other tile sizes without -1 entries, several pattern
    blocks per tile row at 32); bytes without a solid pixel are left as they were."""
    from heoslice.grading.halftone import bayer_matrix, layer_tile

    rng = np.random.default_rng(seed)
    layer = int(rng.integers(0, 1000))
    if size != 16:
        missing = "none"
    tile = layer_tile(layer) if size == 16 else (bayer_matrix(size) + 0.5) / (size * size)
    level = np.rint(tile * size * size - 0.5).astype(np.int64)
    case = wide_halftone_case(rng, channels, missing, size * size)
    assert_droplet_bits_are_the_per_pixel_choice(rng, case, channels, tile, level, layer)
