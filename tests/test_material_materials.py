"""Colour specs, the materials file, and the eq. 1 blend (corrected).

References: CSS colour values written out, TOML files written by hand, and eq. 1 with
its misprint corrected (M1 where f <= 0, M2 where f >= 1, M1 + f (M2 - M1) between).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from heoslice.errors import InputError
from heoslice.material import (
    DEFAULT_MATERIALS,
    Material,
    blend,
    check_one_per_channel,
    is_channel,
    material_roles,
    parse_color,
    read_materials_file,
    resolve_material,
    shared_channel,
    to_rgb8,
    with_table_channels,
)

channel = st.integers(0, 255)


@pytest.mark.parametrize("text, rgb", [
    ("red", (255, 0, 0)), ("Lime", (0, 255, 0)), ("green", (0, 128, 0)), ("white", (255, 255, 255)),
    ("#0f0", (0, 255, 0)), ("#00FF00", (0, 255, 0)), ("#102030", (16, 32, 48)),
    ("0,255,0", (0, 255, 0)), (" 12, 34 ,56 ", (12, 34, 56)), ("(1,2,3)", (1, 2, 3)), ((7, 8, 9), (7, 8, 9)),
])
def test_parse_color(text, rgb):
    """Names (CSS), #rgb / #rrggbb and r,g,b all give the (r, g, b) triple."""
    assert parse_color(text) == rgb


@pytest.mark.parametrize("text", ["nope", "1,2", "1,2,3,4", "256,0,0", "-1,0,0", "1.5,2,3", "#12345", "", "#ggg"])
def test_parse_color_refusals(text):
    """Anything else is an InputError whose message quotes the text."""
    with pytest.raises(InputError) as caught:
        parse_color(text)
    assert repr(text.strip()) in str(caught.value)


@given(r=channel, g=channel, b=channel)
def test_parse_color_round_trip(r, g, b):
    """Every triple survives both the r,g,b and the #hex spelling."""
    assert parse_color(f"{r},{g},{b}") == (r, g, b)
    assert parse_color(f"#{r:02x}{g:02x}{b:02x}") == (r, g, b)


def test_blend_boundaries():
    """Eq. 1 corrected: exactly M1 for f <= 0, exactly M2 for f >= 1, the midpoint at f = 0.5."""
    m1, m2 = (240, 240, 240), (0, 255, 0)
    f = np.array([-5.0, -1e-9, 0.0, 0.5, 1.0, 1.0 + 1e-9, 7.0, np.inf, -np.inf])
    out = blend(m1, m2, f)
    assert out.shape == (len(f), 3)
    for row in (0, 1, 2, 8):
        assert tuple(out[row]) == m1
    for row in (4, 5, 6, 7):
        assert tuple(out[row]) == m2
    assert tuple(out[3]) == (120.0, 247.5, 120.0)
    materials = blend(Material("a", m1), Material("b", m2), f)
    assert np.array_equal(materials, out)


@given(f=st.floats(0, 1), c1=st.tuples(channel, channel, channel), c2=st.tuples(channel, channel, channel))
def test_blend_is_linear_between(f, c1, c2):
    """For 0 < f < 1 the blend is M1 + f (M2 - M1) (not the misprinted f (M1 - M2) + M1) and stays in the box."""
    out = blend(c1, c2, np.array([f]))[0]
    assert np.allclose(out, np.array(c1) + f * (np.array(c2) - np.array(c1)), rtol=0, atol=1e-12)
    low, high = np.minimum(c1, c2), np.maximum(c1, c2)
    assert np.all(out >= low - 1e-9) and np.all(out <= high + 1e-9)
    assert to_rgb8(out[None]).dtype == np.uint8


def test_default_materials():
    """Without a file: M1 light grey on channel 1, M2 green (0, 255, 0) on channel 2."""
    table = read_materials_file(None).materials
    assert list(table) == ["M1", "M2"]
    assert table["M1"] == Material("M1", (240, 240, 240), 1)
    assert table["M2"] == Material("M2", (0, 255, 0), 2)
    assert table is not DEFAULT_MATERIALS  # callers may change their copy
    assert read_materials_file(None).shells() == {}


def test_materials_file(tmp_path):
    """A TOML file names materials (colour in any spelling, channel) and assigns shells by number; a material
    without a channel takes the lowest one no material of the file names (tumour: 3)."""
    path = tmp_path / "mats.toml"
    path.write_text(
        '[materials.gel]\ncolor = "#f0f0f0"\nchannel = 1\n'
        '[materials.cells]\ncolor = [0, 200, 0]\nchannel = 2\n'
        '[materials.tumour]\ncolor = "red"\n'
        '[shells]\n1 = "tumour"\n2 = "0,0,255"\n'
    )
    table = read_materials_file(path).materials
    assert table == {"gel": Material("gel", (240, 240, 240), 1), "cells": Material("cells", (0, 200, 0), 2),
                     "tumour": Material("tumour", (255, 0, 0), 3)}
    shells = read_materials_file(path).shells()
    assert shells == {1: table["tumour"], 2: Material("0,0,255", (0, 0, 255), None)}


@pytest.mark.parametrize("text, fragment", [
    ("[materials.a]\nchannel = 1\n", "has no 'color'"),
    ("[materials.a]\ncolor = 'blurple'\n", "does not parse"),
    ("[materials.a]\ncolor = 'red'\nchannel = 0\n", "channel must be a whole number from 1 to 254"),
    ("[materials.a]\ncolor = 'red'\nchannel = 255\n", "channel must be a whole number from 1 to 254"),
    ("[materials.a]\ncolor = 'red'\nchannel = 'one'\n", "channel must be"),
    ("[materials.a]\ncolor = 'red'\nink = 3\n", "unknown key"),
    ("[materials]\n", "no \\[materials.NAME\\]"),
    ("materials = 3\n", "no \\[materials.NAME\\]"),
    ("[materials.a\ncolor = 'red'\n", "not a valid TOML"),
    ("a = " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
    ("[materials.a]\ncolor = 'red'\n[shells]\nliver = 'a'\n", "not a shell number"),
    ("[materials.a]\ncolor = 'red'\n[shells]\n1 = 'b'\n", "neither a material name"),
])
def test_materials_file_refusals(tmp_path, text, fragment):
    """Each malformed file is one InputError naming the file and the problem."""
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=fragment) as caught:
        read_materials_file(path).shells()
    assert str(path) in str(caught.value)


def test_missing_materials_file(tmp_path):
    """A missing file or a directory is an InputError naming it."""
    with pytest.raises(InputError, match="no such file"):
        read_materials_file(tmp_path / "absent.toml").materials
    with pytest.raises(InputError, match="is a directory"):
        read_materials_file(tmp_path).materials


def test_resolve_material():
    """A name from the table (exact, then any case) wins; otherwise a colour spec makes an unnamed material."""
    table = {"gel": Material("gel", (1, 2, 3), 1), "Red": Material("Red", (9, 9, 9), 2)}
    assert resolve_material("gel", table) is table["gel"]
    assert resolve_material("GEL", table) is table["gel"]
    assert resolve_material("red", table) is table["Red"]  # the table's name shadows the CSS colour
    assert resolve_material("#0000ff", table) == Material("#0000ff", (0, 0, 255), None)
    with pytest.raises(InputError, match="neither a material name"):
        resolve_material("unobtainium", table)


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_a_materials_file_that_is_not_a_regular_file_is_refused_at_once(tmp_path, special):
    """--materials /dev/zero or a FIFO is one line (exit 2) naming it, read no further (no hang, no 10 GB read)."""
    import os
    import subprocess
    import sys

    if special == "fifo":
        special = tmp_path / "materials.toml"
        os.mkfifo(special)
    model = tmp_path / "vase.ply"
    model.write_bytes((Path(__file__).resolve().parents[1] / "examples" / "vase.ply").read_bytes())
    done = subprocess.run([sys.executable, "-m", "heoslice", "--no-config", "slice", str(model), "--grade", "linear",
                           "--materials", str(special), "-o", str(tmp_path / "s")], capture_output=True, text=True,
                          timeout=30)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1 and str(special) in done.stderr


def test_a_materials_file_larger_than_the_limit_is_refused_before_reading(tmp_path):
    """A materials file over MAX_MATERIALS_FILE_BYTES is refused by its size, naming the limit."""
    from heoslice.material.materials import MAX_MATERIALS_FILE_BYTES, read_materials_file

    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (MAX_MATERIALS_FILE_BYTES + 1))
    with pytest.raises(InputError, match="limit"):
        read_materials_file(big).materials


def test_nearest_materials_maps_display_colours_to_themselves_and_others_to_the_closest():
    """A material's own display colour maps to it; any other colour to the material whose display colour is
    nearest in RGB (checked against a literal loop over the palette); ties go to the first listed."""
    from heoslice.material import Material, nearest_materials

    palette = [Material("gel", (240, 240, 240), 1), Material("cells", (0, 255, 0), 2), Material("red", (255, 0, 0), 3)]
    rng = np.random.default_rng(3)
    colors = np.vstack([[m.color for m in palette], rng.integers(0, 256, (200, 3))])
    got = nearest_materials(colors, palette)
    expected = [min(range(3), key=lambda k: sum((int(c[i]) - palette[k].color[i]) ** 2 for i in range(3)))
                for c in colors]
    assert list(got[:3]) == [0, 1, 2]
    assert list(got) == expected
    twins = [Material("a", (10, 10, 10)), Material("b", (10, 10, 10))]
    assert list(nearest_materials([[10, 10, 10]], twins)) == [0]


@pytest.mark.parametrize("named, shared", [
    ([], None),
    ([("a", 1), ("b", 2), ("c", None), ("d", None)], None),
    ([("a", 2), ("b", None), ("c", 2), ("d", 1), ("e", 1)], (1, ["d", "e"])),
    ([("a", 3), ("b", 3), ("c", 3)], (3, ["a", "b", "c"])),
])
def test_shared_channel_is_the_lowest_channel_named_twice(named, shared):
    """The one-material-per-channel rule of slice, verify and print: the lowest channel two or more materials
    name, with all their names in order; unassigned materials (None) share nothing."""
    assert shared_channel(named) == shared


def test_a_printer_channel_is_a_whole_number_from_one():
    """JSON's true, 0, 255 (past the one byte of a job's channel count), negative numbers and 1.0 are no
    printer channel; 1 and 254 are."""
    assert [is_channel(value) for value in (1, 254, 0, 255, -1, 1.0, True, None, "1")] == [True, True] + [False] * 7


@pytest.mark.parametrize("channels, resolved", [
    ((1, 2, None), (1, 2, 3)),
    ((None, None, None), (1, 2, 3)),
    ((None, 1, None, 4), (2, 1, 3, 4)),
    ((3, None, 3), (3, 1, 3)),
])
def test_a_tables_unassigned_materials_take_the_lowest_channels_it_leaves(channels, resolved):
    """Each material of a table without a channel gets the lowest channel no material of the table names, in
    table order (named ones, even shared, are kept: sharing is refused where masks meet, not here)."""
    table = {f"m{k}": Material(f"m{k}", (k, k, k), channel) for k, channel in enumerate(channels)}
    assert tuple(m.channel for m in with_table_channels(table).values()) == resolved


def test_three_materials_on_one_channel_are_named_in_one_sentence():
    """The refusal names every material on the shared channel: "'a', 'b' and 'c' all print on channel 2"."""
    materials = [Material(name, (k, 0, 0), 2) for k, name in enumerate("abc")]
    with pytest.raises(InputError, match="'a', 'b' and 'c' all print on channel 2, but the masks need"):
        check_one_per_channel(materials, "the masks")


THREE = {name: Material(name, color, channel) for name, color, channel in
         (("gel", (240, 240, 240), 1), ("cells", (0, 255, 0), 2), ("tumour", (200, 0, 0), 3))}


@pytest.mark.parametrize("table, start, target, m1, m2", [
    (DEFAULT_MATERIALS, None, None, "M1", "M2"),
    (DEFAULT_MATERIALS, "M2", None, "M2", "M1"),  # the table's second named as the start: M1 is the target
    (DEFAULT_MATERIALS, None, "M1", "M2", "M1"),  # the table's first named as the target: M2 is the start
    (DEFAULT_MATERIALS, "M1", None, "M1", "M2"),
    (DEFAULT_MATERIALS, None, "M2", "M1", "M2"),
    (THREE, "cells", None, "cells", "gel"),
    (THREE, None, "gel", "cells", "gel"),
    (THREE, "tumour", None, "tumour", "cells"),
    (THREE, None, "tumour", "gel", "tumour"),
])
def test_a_role_named_alone_takes_a_partner_other_than_itself(table, start, target, m1, m2):
    """A start or target named alone leaves the other role to the table's default (first, second) unless that is
    the named material itself, then to the table's first other material: never one material in both roles."""
    roles = material_roles(dict(table), start=start, target=target)
    assert (roles.m1.name, roles.m2.name) == (m1, m2)


@pytest.mark.parametrize("start, target", [("M1", "M1"), ("M2", "0,255,0"), ("255,0,0", "255,0,0")])
def test_one_material_in_both_roles_is_refused(start, target):
    """--from and --to naming one material (by name or by its colour) is a one-line error naming both."""
    with pytest.raises(InputError, match="start, target: both name"):
        material_roles(dict(DEFAULT_MATERIALS), start=start, target=target)


def test_the_colour_examples_an_error_gives_are_one_colour():
    """The three ways of writing a colour an unparsable colour's error suggests name one colour: a user copying
    one does not get another (CSS's 'green' is (0, 128, 0), not #00ff00)."""
    import re

    from heoslice.material.materials import COLOUR_EXAMPLES, parse_color

    with pytest.raises(InputError) as raised:
        parse_color("no-such-colour")
    assert COLOUR_EXAMPLES in str(raised.value)
    name, hex_code, triple = re.search(r"'(\w+)', a hex (#[0-9a-f]{6}) or r,g,b ([\d,]+)", COLOUR_EXAMPLES).groups()
    assert parse_color(name) == parse_color(hex_code) == parse_color(triple)
