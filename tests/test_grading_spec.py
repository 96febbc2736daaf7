"""Tests of grading/spec.py: the droplet masks' materials of a GradeSpec and the one look-up of a material's
channel index among them."""

from __future__ import annotations

import pytest

from heoslice.grading import GradeSpec, RegionSpec
from heoslice.material import Material

GEL, CELLS, BONE = Material("gel", (240, 240, 240), 1), Material("cells", (0, 255, 0), 2), Material("bone", (9, 9, 9))


def test_channel_index_is_the_position_among_the_channel_materials():
    """Every material of the masks is found at its own position (repeats of base/second/start/target/shells
    collapse to one), a copy of a material (same name and colour) finds the same index, and a material of the
    same name in another colour is another material."""
    other_gel = Material("gel", (1, 2, 3), 5)
    spec = GradeSpec(regions=RegionSpec(), function=None, target=BONE, start=CELLS, base=GEL, second=CELLS,
                     shells=((0, GEL), (1, other_gel)), mapped=(BONE,))
    materials = spec.channel_materials()
    assert [m.name for m in materials] == ["gel", "cells", "bone", "gel"]
    assert [spec.channel_index(m) for m in materials] == [0, 1, 2, 3]
    assert spec.channel_index(Material("cells", (0, 255, 0), 7)) == 1
    assert spec.channel_index(other_gel) == 3


def test_channel_index_refuses_a_material_not_among_the_masks():
    """A material that has no droplet mask is an error, not an index of another material."""
    spec = GradeSpec(regions=RegionSpec(), function=None, target=None, start=None, base=GEL, second=CELLS)
    with pytest.raises(ValueError, match="bone"):
        spec.channel_index(BONE)
