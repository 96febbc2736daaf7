"""The design record (material/design.py): what color writes, slice reads back exactly; unknown versions and
malformed records are refused; the materials of a design meet a materials table by one rule."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.material import ColorSpec, Material, color_mesh, make_function, ply_bytes, write_ply
from heoslice.material.design import DESIGN_VERSION, Design, ReferenceRecord, settle_materials
from heoslice.mesh import load_mesh

names = st.text(st.characters(min_codepoint=32, max_codepoint=0x24F, exclude_characters="\n\r"), min_size=1,
                max_size=12).filter(lambda s: s.strip() == s and "  " not in s)
colors = st.tuples(*[st.integers(0, 255)] * 3)
materials = st.builds(Material, names, colors, st.one_of(st.none(), st.integers(1, 254)))
finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(start=materials, target=materials, point=st.tuples(finite, finite, finite),
       low=st.floats(0, 100), width=st.floats(1e-3, 1e3), alpha=finite,
       expression=st.sampled_from([None, "0.5 - 0.5*cos(3*pi*r)", "r  **  2"]))
def test_header_round_trip(start, target, point, low, width, alpha, expression):
    """Every field of a design survives to_header -> from_header exactly (names with spaces and non-ASCII
    letters, floats to the bit, an expression's spaces)."""
    function = make_function("expression", expression=expression) if expression else make_function(
        "linear", alpha=alpha)
    design = Design(start, target, ReferenceRecord("point", point), function, (low, low + width), "range",
                    ((1, target),))
    lines = design.to_header()
    assert all("  " not in line and "\n" not in line for line in lines)
    assert Design.from_header(["heoslice color: other", *lines]) == design


def test_a_coloured_ply_reads_back_its_design(tmp_path):
    """The PLY color writes carries the design its ColorSpec asked for, read back from the loaded mesh."""
    source = tmp_path / "vase.ply"
    procedural.vase().export(source)
    red = Material("255,0,0", (255, 0, 0), None)
    spec = ColorSpec(make_function("sine", periods=3), reference="axis", m2=red, r_range=(1.0, 9.0))
    colored = color_mesh(load_mesh(source), spec)
    target = write_ply(tmp_path / "out.ply", colored, ascii=True)
    read = Design.from_header(load_mesh(target).comments)
    assert read == colored.design
    assert read.target == red and read.function == spec.function and read.r_range == (1.0, 9.0)
    assert read.reference.kind == "axis" and read.reference.direction == (0.0, 0.0, 1.0)
    assert read.range_from == "range"


def test_without_a_range_the_largest_distance_is_recorded(tmp_path):
    source = tmp_path / "ball.ply"
    procedural.sphere(radius=5.0).export(source)
    colored = color_mesh(load_mesh(source), ColorSpec(reference="point", at=(1.0, 0.0, 0.0)))
    distance = np.linalg.norm(colored.vertices - (1.0, 0.0, 0.0), axis=1).max()
    assert colored.design.r_range == (0.0, float(distance)) and colored.design.range_from == "max"


@pytest.mark.parametrize("line, message", [
    ("heoslice design 2 start {}", "version 2"),
    ("heoslice design 1 start {nope", "not valid JSON"),
    ("heoslice design 1 start", "malformed"),
])
def test_bad_records_are_refused(line, message):
    with pytest.raises(InputError, match=message):
        Design.from_header([line], "m.ply")


def test_a_record_missing_a_field_is_refused():
    lines = [line for line in _design().to_header() if " range " not in line]
    with pytest.raises(InputError, match="lacks range"):
        Design.from_header(lines, "m.ply")


def _design(start=Material("gel", (240, 240, 240), 1), target=Material("cells", (0, 255, 0), 2)) -> Design:
    return Design(start, target, ReferenceRecord("plane", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
                  make_function("linear"), (0.0, 10.0))


TABLE = {"gel": Material("gel", (240, 240, 240), 1), "cells": Material("cells", (0, 255, 0), 2),
         "tumour": Material("tumour", (200, 0, 0), 3)}


def test_settle_keeps_the_designs_materials_without_a_table():
    design = _design(target=Material("255,0,0", (255, 0, 0), None))
    assert settle_materials(design, None, "none") is design


def test_settle_takes_the_table_material_by_name_or_by_an_unchannelled_colour():
    design = _design(start=Material("Cells", (0, 255, 0), 2), target=Material("200,0,0", (200, 0, 0), None))
    settled = settle_materials(design, TABLE, "mats.toml")
    assert settled.start == TABLE["cells"] and settled.target == TABLE["tumour"]


@pytest.mark.parametrize("material, message", [
    (Material("bone", (1, 2, 3), 4), "'bone' (1,2,3, channel 4) is not in mats.toml"),
    (Material("cells", (0, 0, 255), 2), "is 'cells' (0,0,255, channel 2), but mats.toml has 'cells' (0,255,0"),
    (Material("cells", (0, 255, 0), 5), "channel 5), but mats.toml has 'cells' (0,255,0, channel 2)"),
])
def test_settle_refuses_a_disagreeing_material_naming_both(material, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        settle_materials(_design(target=material), TABLE, "mats.toml", "m.ply")


def test_scaled_design_scales_its_millimetres_only():
    design = _design()
    scaled = design.scaled(1000.0)
    assert scaled.r_range == (0.0, 10000.0) and scaled.reference.direction == (0.0, 0.0, 1.0)
    assert scaled.function == design.function and math.isclose(scaled.reference.surface_scale, 1000.0)
