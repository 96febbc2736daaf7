"""Tests of layers/planes.py: the one layer-count formula and its tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.errors import InputError
from heoslice.layers.planes import layer_count, plane_heights


@pytest.mark.parametrize("z_min, z_max, h, count", [
    (0.0, 1.0, 0.1, 10),  # an exact multiple (up to rounding) adds no extra layer
    (2.0, 3.05, 0.1, 11),
    (0.0, float(np.float32(0.1)), 0.1, 1),  # one layer high in float32
    (0.0, float(np.float32(6.0)), 0.2, 30),
    (5.0, 5.0, 0.1, 1),  # a flat part still has a layer
    (0.0, 60.0, 1000.0, 1),
    (0.0, 1.0 + 1e-3, 0.1, 11),  # a real sliver above a whole number of layers is a layer
])
def test_layer_count_is_the_ceiling_of_height_over_layer_within_rounding(z_min, z_max, h, count):
    """ceil((z_max - z_min) / h), at least 1, less the coordinates' float32 rounding (and never more)."""
    assert layer_count(z_min, z_max, h) == count
    assert len(plane_heights(z_min, z_max, h)) == count


def test_layer_count_stops_at_a_limit_and_refuses_what_it_cannot_count():
    """With a limit, a count above it is limit + 1 without being computed (even an overflowing ratio);
    without one, an overflowing ratio and a non-positive layer are input errors naming layer_height_mm."""
    assert layer_count(0.0, 1e300, 1e-3, limit=1000) == 1001
    assert layer_count(0.0, 100.0, 1e-3, limit=1000) == 1001
    assert layer_count(0.0, 1.0, 0.1, limit=1000) == 10
    for h in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="^layer_height_mm: "):
            layer_count(0.0, 1.0, h)
    with pytest.raises(InputError, match="^layer_height_mm: "):
        layer_count(-1e308, 1e308, 1e-300)
