"""Tests of heoslice.grading.materials: contour values at the cells, start mixes and shells in the droplet masks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import shapely
from helpers import PX, circle, grid_around, layer, pixel_centres
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.grading import (
    GradeSpec,
    RegionSpec,
    contour_values,
    family_field,
    layer_families,
    layer_regions,
    render_graded,
)
from heoslice.layers.rasterising import solid_mask
from heoslice.material import DEFAULT_MATERIALS, Material, make_function

pytestmark = pytest.mark.usefixtures("lattice_fit_for_every_family")  # conftest.py: small families on the lattice too


def composed_masks(points, offsets, area, parent, shells, mask, grid, spec, layer, point_material=None):
    """The droplet masks composed in numpy from their definition, an independent reference for the compiled
    path: each labelled pixel's mix is its family's start mix at its lattice cell (paint_cells) moved by
    its sub-region's fraction towards the target (eq. 1), halftoned by helpers.droplet_masks;
    solid pixels outside every family jet the base material."""
    from helpers import droplet_masks, paint_cells

    from heoslice.grading.materials import family_starts as _family_starts
    from heoslice.grading.materials import target_fractions as _target_fractions

    regions = layer_regions(points, offsets, area, parent, mask, grid, spec.regions)
    materials = spec.channel_materials()
    masks = np.zeros((len(materials), grid.height, grid.width), dtype=bool)
    if regions.fields:
        mixes = _family_starts(regions, spec, shells, point_material)
        fraction = paint_cells(regions, mixes)
        if spec.target is not None and spec.function is not None:
            target_mix = np.zeros(len(materials), dtype=np.float32)
            target_mix[materials.index(spec.target)] = 1.0
            share = np.take(_target_fractions(regions, spec).astype(np.float32), regions.label)
            fraction += share[..., None] * (target_mix - fraction)
        b = regions.box
        masks[:, b[0]:b[1], b[2]:b[3]] = droplet_masks(np.moveaxis(fraction, -1, 0), regions.label > 0, layer,
                                                       origin=(b[0], b[2]))
    masks[materials.index(spec.base)] |= mask & ~masks.any(axis=0)
    return masks


def test_layer_without_families_jets_the_base_material():
    """Solid pixels no family labels (here: a lone clockwise ring, a broken mesh) still get exactly one
    material, the base one, in the fast droplet path, render_graded and the numpy composition."""
    from heoslice.grading import droplet_planes

    points, offsets, area, parent = layer(circle(3.0, clockwise=True))
    grid = grid_around(3.5)
    mask = solid_mask(circle(3.0), np.array([0, 720]), grid)  # solid pixels, but the only loop is a hole
    spec = GradeSpec(RegionSpec(), make_function("linear"), DEFAULT_MATERIALS["M2"], None, DEFAULT_MATERIALS["M1"])
    masks = composed_masks(points, offsets, area, parent, None, mask, grid, spec, 0)
    planes = np.unpackbits(droplet_planes(points, offsets, area, parent, None, mask, grid, spec, 0), axis=2,
                           count=grid.width).astype(bool)
    assert np.array_equal(render_graded(points, offsets, area, parent, None, mask, grid, spec, 0,
                                        channels=True).masks, planes)
    assert mask.any()
    assert np.array_equal(masks, planes)
    assert np.array_equal(masks[0], mask) and not masks[1:].any()


def test_nested_shell_keeps_its_material():
    """A lesion shell inside an organ (both counter-clockwise) is its own family; its pixels carry the
    lesion's shell material in the graded image, the organ around it is graded to the target."""
    organ, lesion = circle(9.0), circle(2.5, 360, (3.0, 1.0))
    points, offsets, area, parent = layer(organ, lesion)
    grid = grid_around(9.5)
    mask = solid_mask(points, offsets, grid)
    tumour = Material("tumour", (200, 0, 0), 3)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.5), make_function("linear"), DEFAULT_MATERIALS["M2"], None,
                     DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"], shells=((1, tumour),))
    out = render_graded(points, offsets, area, parent, np.array([0, 1]), mask, grid, spec, 0, channels=True)
    x, y = pixel_centres(grid, (0, grid.height, 0, grid.width))
    in_lesion = np.hypot(x - 3.0, y - 1.0) < 2.5 - PX
    assert np.all(out.image[in_lesion][:, :3] == tumour.color)
    materials = spec.channel_materials()
    assert out.masks[materials.index(tumour)][in_lesion].all()
    organ_only = mask & ~in_lesion & (np.hypot(x - 3.0, y - 1.0) > 2.5 + PX)
    assert not out.masks[materials.index(tumour)][organ_only].any()
    deep = organ_only & (np.hypot(x, y) < 0.3)
    near_edge = organ_only & (np.hypot(x, y) > 8.9)
    assert out.image[deep][:, 1].mean() > out.image[near_edge][:, 1].mean()
    assert np.all(out.masks.sum(axis=0) == mask)


@pytest.mark.parametrize("per_vertex", [False, True])
def test_droplet_planes_are_render_graded_masks_bit_for_bit(per_vertex):
    """The fast droplet path (one compiled pass, a per-label table where a family's start mix is uniform)
    gives exactly the masks composed in numpy from their definition (and render_graded's): an organ
    with a hole, an island in the hole and a lesion shell of its own material, on two layers; with
    per-vertex material fractions every family's start mix varies by cell, so the per-pixel branch
    is exercised too."""
    from heoslice.grading import droplet_planes

    organ, hole, island, lesion = (circle(9.0), circle(3.0, 240, (-3.0, -2.0), clockwise=True),
                                   circle(1.0, 120, (-3.0, -2.0)), circle(2.0, 200, (4.0, 2.0)))
    points, offsets, area, parent = layer(organ, hole, island, lesion)
    grid = grid_around(9.5)
    mask = solid_mask(points, offsets, grid)
    tumour = Material("tumour", (200, 0, 0), 3)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.4), make_function("sine", periods=1.5), Material("green", (0, 255, 0)),
                     None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"], shells=((3, tumour),))
    shells = np.array([0, 0, 2, 3])
    point_material = np.random.default_rng(0).uniform(0, 1, len(points)) if per_vertex else None
    for index in (0, 7):
        expected = composed_masks(points, offsets, area, parent, shells, mask, grid, spec, index, point_material)
        planes = droplet_planes(points, offsets, area, parent, shells, mask, grid, spec, index,
                                point_material=point_material)
        got = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
        assert np.array_equal(got, expected)
        assert np.array_equal(droplet_planes(points, offsets, area, parent, shells, None, grid, spec, index,
                                             point_material=point_material, packed=np.packbits(mask, axis=1)), planes)
        assert np.array_equal(render_graded(points, offsets, area, parent, shells, mask, grid, spec, index,
                                            channels=True, point_material=point_material).masks, got)
        assert np.array_equal(got.sum(axis=0), mask.astype(int))
        assert all(plane.any() for plane in got[[0, 2, 3]])


def test_many_materials_halftone_like_render_graded():
    """With eight or more droplet materials (shells of their own, per-vertex fractions), the fast droplet
    path still equals the masks composed in numpy bit for bit and partitions the solid pixels."""
    from heoslice.grading import droplet_planes

    rings = [circle(9.0)] + [circle(0.8, 90, (3.0 * np.cos(a), 3.0 * np.sin(a))) for a in np.linspace(0, 6, 8)]
    points, offsets, area, parent = layer(*rings)
    grid = grid_around(9.5)
    mask = solid_mask(points, offsets, grid)
    shells = np.arange(len(rings))
    own = tuple((i, Material(f"s{i}", (10 * i, 200 - 10 * i, 7 * i), i + 3)) for i in range(1, len(rings)))
    spec = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("quadratic"), Material("green", (0, 255, 0)), None,
                     DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"], shells=own)
    assert len(spec.channel_materials()) >= 8
    point_material = np.random.default_rng(1).uniform(0, 1, len(points))
    for index in (0, 3):
        expected = composed_masks(points, offsets, area, parent, shells, mask, grid, spec, index, point_material)
        got = np.unpackbits(droplet_planes(points, offsets, area, parent, shells, mask, grid, spec, index,
                                           point_material=point_material), axis=2, count=grid.width).astype(bool)
        assert np.array_equal(got, expected)
        assert np.array_equal(got.sum(axis=0), mask.astype(int))


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_contour_values_interpolate_between_the_layers_points_where_edges_span_several(seed):
    """A ring with points put on its edges (left out of the edges, :func:`ring_edges`) and a value at every
    point: the value taken at each cell's nearest ring point is the one interpolated along the ring between
    the points on either side of it (shapely's position along the ring, numpy's interp), as if no point
    had been left out."""
    rng = np.random.default_rng(seed)
    corners = circle(4.0, int(rng.integers(5, 40)))
    ring = []
    for i, corner in enumerate(corners):
        ring.append(corner)
        following = corners[(i + 1) % len(corners)]
        ring += [corner + t * (following - corner) for t in np.sort(rng.uniform(0.01, 0.99, rng.integers(0, 4)))]
    ring = np.array(ring)
    values = rng.uniform(0.0, 1.0, (len(ring), 2))
    points, offsets, area, parent = layer(ring)
    field = family_field(points, offsets, layer_families(area, parent)[0], grid_around(4.5), RegionSpec())
    assert len(field.start_edges().x) == len(corners)
    got = contour_values(field, values)
    foot, _ = field.nearest()
    closed = shapely.LineString(np.vstack([ring, ring[:1]]))
    along = shapely.line_locate_point(closed, shapely.points(foot[0].ravel(), foot[1].ravel()))
    knots = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(np.vstack([ring, ring[:1]]), axis=0).T))])
    for column in range(2):
        expected = np.interp(along, knots, np.append(values[:, column], values[0, column]))
        np.testing.assert_allclose(got[..., column].ravel(), expected, atol=1e-9)


def test_a_contour_of_one_value_gives_it_to_every_cell_without_measuring_nearest_points():
    """Every point of the ring holding one value (a gradient along z, through a layer): every cell takes
    exactly that value, and the cells' nearest ring points are never measured (they would be the costliest
    part of a coloured layer that is not graded)."""
    ring = circle(4.0, 97)
    points, offsets, area, parent = layer(ring)
    field = family_field(points, offsets, layer_families(area, parent)[0], grid_around(4.5), RegionSpec())

    def not_measured():
        raise AssertionError("nearest points measured")

    value = np.array([0.3125, 0.6875])
    got = contour_values(replace(field, nearest=not_measured), np.tile(value, (len(ring), 1)))
    assert got.shape == (field.lattice.rows, field.lattice.cols, 2)
    assert (got == value).all()
    varied = np.tile(value, (len(ring), 1))
    varied[5, 0] = 0.5
    with pytest.raises(AssertionError, match="nearest points measured"):
        contour_values(replace(field, nearest=not_measured), varied)


def test_a_contour_whose_values_may_stand_as_one_gives_the_first_to_every_cell_without_measuring():
    """contour_values asks ``as_one`` about the ring points' least and greatest values (per column); where it
    says they may stand as one, every cell takes the first point's value and no nearest point is measured,
    where it says no, the cells' own values are measured."""
    ring = circle(4.0, 97)
    points, offsets, area, parent = layer(ring)
    field = family_field(points, offsets, layer_families(area, parent)[0], grid_around(4.5), RegionSpec())
    values = np.column_stack([np.linspace(0.3, 0.3 + 1e-9, len(ring)), np.linspace(0.7, 0.7 - 1e-9, len(ring))])
    asked = []

    def as_one(low, high):
        asked.append((low, high))
        return True

    def not_measured():
        raise AssertionError("nearest points measured")

    knots = values[field.start_edges().knot_point]
    got = contour_values(replace(field, nearest=not_measured), values, as_one)
    assert got.shape == (field.lattice.rows, field.lattice.cols, 2) and (got == knots[0]).all()
    assert np.array_equal(asked[0][0], knots.min(axis=0)) and np.array_equal(asked[0][1], knots.max(axis=0))
    measured = contour_values(field, values, lambda low, high: False)
    assert np.array_equal(measured, contour_values(field, values)) and not (measured == knots[0]).all()


@pytest.mark.parametrize("graded", [False, True])
def test_contour_materials_that_differ_in_rounding_give_the_measured_masks_unmeasured(graded, monkeypatch):
    """A coloured layer whose contour points' materials differ in their last bits (a z gradient, as
    ``heoslice color`` makes one): droplet_planes takes them as one (jets_as_one says so for every family)
    and gives the masks the numpy composition makes from every cell's own measured mix; without a gradient
    it measures no cell's nearest contour point and makes no ring's edge tree (no distance is measured)."""
    from heoslice.grading import droplet_planes, droplets, search
    from heoslice.grading import field as field_module

    points, offsets, area, parent = layer(circle(6.0, 300), circle(2.0, 120, (1.0, 0.5), clockwise=True))
    grid = grid_around(6.5)
    mask = solid_mask(points, offsets, grid)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("linear") if graded else None,
                     Material("green", (0, 255, 0)) if graded else None, None, DEFAULT_MATERIALS["M1"],
                     DEFAULT_MATERIALS["M2"])
    point_material = 0.63 + np.random.default_rng(2).uniform(-6e-8, 6e-8, len(points))  # of M2, the rest M1
    measured, taken, trees = [], [], []
    original, as_one, tree = field_module.ring_measures, droplets.jets_as_one, search.ring_tree
    monkeypatch.setattr(field_module, "ring_measures", lambda *a: measured.append(1) or original(*a))
    monkeypatch.setattr(droplets, "jets_as_one", lambda *a: taken.append(as_one(*a)) or taken[-1])
    monkeypatch.setattr(search, "ring_tree", lambda *a: trees.append(1) or tree(*a))
    got = np.unpackbits(droplet_planes(points, offsets, area, parent, None, mask, grid, spec, 5,
                                       point_material=point_material), axis=2, count=grid.width).astype(bool)
    cells_measured = len(measured)
    assert taken and all(taken)
    if not graded:
        assert not trees
    expected = composed_masks(points, offsets, area, parent, None, mask, grid, spec, 5, point_material)
    assert len(measured) > cells_measured
    if not graded:
        assert cells_measured == 0
    assert np.array_equal(got, expected)
    assert got[0].any() and got[1].any()
