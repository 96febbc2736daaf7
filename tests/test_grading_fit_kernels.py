"""heoslice.grading.fit_kernels: a one-ring family's lattice fit in one compiled call labels every pixel as the
general fit's steps label it (field._fitted_index, the path of families of several ring sets)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import circle, grid_around, layer, rough_outline

from heoslice.grading import RegionSpec, family_field, layer_families
from heoslice.grading import field as field_module
from heoslice.layers.rasterising import solid_mask

pytestmark = pytest.mark.usefixtures("lattice_fit_for_every_family")  # conftest.py: small families on the lattice too


def notched_square(half: float) -> np.ndarray:
    """A square with a V notch cut into its top side (a reflex vertex and two sharp corners), counter-clockwise."""
    return np.array([[-half, -half], [half, -half], [half, half], [0.4, half], [0.0, 0.2 * half], [-0.4, half],
                     [-half, half]])


SHAPES = {
    "disc": lambda: circle(6.0),
    "rough outline": lambda: rough_outline(3),
    "notched square": lambda: notched_square(5.0),
    "thin slot": lambda: np.array([[-12.0, -0.7], [12.0, -0.7], [12.0, 0.7], [-12.0, 0.7]]),
}


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize(("masked", "label_base"), [(False, 0), (True, 7)])
def test_the_one_call_fit_labels_as_the_stepwise_fit(monkeypatch, name, masked, label_base):
    """Through family_field, the compiled one-ring fit and the general fit's steps give the same labels, bit for
    bit, with and without the layer's mask and a label base: discs (quadratic cells), rough and notched
    outlines (refined cells measured per pixel) and a slot thinner than a few cells."""
    points, offsets, area, parent = layer(SHAPES[name]())
    grid = grid_around(14.0)
    family = layer_families(area, parent)[0]
    mask = solid_mask(points, offsets, grid) if masked else None
    real, compared, steps = field_module._one_ring_index, [], []
    for step in ("curve_cells", "refine_cells"):
        monkeypatch.setattr(field_module, step, _counted(getattr(field_module, step), step, steps))

    def both(lattice, grid, layout, rings, measured, shape, mask, label_base, dtype):
        expected = field_module._fitted_index(lattice, grid, layout, [rings], [measured], shape, mask, label_base,
                                              dtype)
        got = real(lattice, grid, layout, rings, measured, shape, mask, label_base, dtype)
        compared.append(got.dtype == expected.dtype and np.array_equal(got, expected))
        return got

    monkeypatch.setattr(field_module, "_one_ring_index", both)
    field = family_field(points, offsets, family, grid, RegionSpec(nozzle_mm=0.25), mask=mask, label_base=label_base)
    assert field.layout.count > 1
    assert compared == [True]
    assert steps  # some cells took their quadratic or were measured per pixel: the fit's every step ran


def _counted(function, name: str, calls: list):
    """``function``, noting its ``name`` in ``calls`` at each call."""
    def counting(*args, **kwargs):
        calls.append(name)
        return function(*args, **kwargs)
    return counting
