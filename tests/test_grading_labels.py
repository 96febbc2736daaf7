"""Tests of heoslice.grading: eq. 8 band counts, eq. 9-10 weights, sub-regions against analytic
fields and shapely's round-join offsets, nested shells."""

from __future__ import annotations

import contextlib
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest
import shapely
from helpers import (
    brute_squared,
    random_rings,
    ring_set,
    ring_weights,
    subregion_index,
    tree_of,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.errors import InputError
from heoslice.grading import (
    GradeSpec,
    GradingCache,
    RegionSpec,
    band_count,
    contour_values,
    edges,
    family_field,
    labels,
    layer_families,
    layer_regions,
    render_graded,
    search,
)
from heoslice.grading import field as field_module
from heoslice.grading import lattice as lattice_module
from heoslice.grading.cache import RingMemo
from heoslice.grading.edges import ring_edges
from heoslice.layers.rasterising import Grid, solid_mask
from heoslice.material import DEFAULT_MATERIALS, Material, make_function

PX = 25.4 / 600


@pytest.fixture(autouse=True, scope="module")
def lattice_fit_for_every_family():
    """Every family here is fitted on the lattice however small (most test shapes are below
    field_module.DIRECT_PIXELS); the tests of the exact per-pixel path ask for it with :func:`exact_per_pixel`."""
    saved = field_module.DIRECT_PIXELS
    field_module.DIRECT_PIXELS = 0
    yield
    field_module.DIRECT_PIXELS = saved


@contextmanager
def exact_per_pixel():
    """Every family takes each pixel's exact distances (field_module._exact_index), however large."""
    saved = field_module.DIRECT_PIXELS
    field_module.DIRECT_PIXELS = 10 ** 12
    try:
        yield
    finally:
        field_module.DIRECT_PIXELS = saved


def circle(radius: float, count: int = 720, center=(0.0, 0.0), clockwise: bool = False) -> np.ndarray:
    """(count, 2) polygon approximating a circle (sag below 1e-4 mm for the radii used)."""
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    ring = np.column_stack([center[0] + radius * np.cos(angle), center[1] + radius * np.sin(angle)])
    return ring[::-1] if clockwise else ring


def layer(*rings):
    """(points, offsets, signed areas, parents) of loops given outermost first; a ring's parent is the
    smallest earlier ring containing its first point."""
    points = np.concatenate(rings)
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in rings])])
    area = np.array([shapely.Polygon(r).area * (1 if shapely.LinearRing(r).is_ccw else -1) for r in rings])
    parent = np.full(len(rings), -1)
    for i, ring in enumerate(rings):
        containing = [j for j in range(i) if shapely.Polygon(rings[j]).contains(shapely.Point(ring[0]))]
        if containing:
            parent[i] = min(containing, key=lambda j: abs(area[j]))
    return points, offsets, area, parent


def grid_around(half_mm: float) -> Grid:
    cells = int(np.ceil(2 * half_mm / PX))
    return Grid(width=cells, height=cells, x_left=-cells * PX / 2, y_top=cells * PX / 2, px=PX, py=PX)


def pixel_centres(grid: Grid, box):
    r0, r1, c0, c1 = box
    x = grid.x_left + (np.arange(c0, c1) + 0.5) * grid.px
    y = grid.y_top - (np.arange(r0, r1) + 0.5) * grid.py
    return np.meshgrid(x, y)


def field_on_mask(points, offsets, area, parent, grid, spec):
    """(k image over the family box, solid mask over the box, field) of the first family."""
    family = layer_families(area, parent)[0]
    field = family_field(points, offsets, family, grid, spec)
    r0, r1, c0, c1 = field.box
    mask = solid_mask(points, offsets, grid)[r0:r1, c0:c1]
    return field.index.astype(np.int64), mask, field


def assert_within_one_pixel(k, expected, band_coordinate, mask, slope_px, limit_px: float = 1.0):
    """Pixels whose sub-region differs from the expected one lie within ``limit_px`` pixels of a band boundary."""
    wrong = mask & (k != expected)
    distance_px = np.abs(band_coordinate - np.rint(band_coordinate)) / slope_px
    assert np.all(np.abs(k - expected)[wrong] <= 1)
    assert np.all(distance_px[wrong] <= limit_px), distance_px[wrong].max()
    assert wrong.sum() < 0.05 * mask.sum()


@given(st.floats(0.01, 500.0), st.floats(0.01, 5.0))
def test_band_count_is_eq8(length, nozzle):
    """N_R = int(L_S / D_N) (eq. 8), and never fewer than one sub-region."""
    assert band_count(length, nozzle) == max(1, int(np.floor(length / nozzle + 1e-9)))


def test_band_count_examples():
    """Rings 6 mm apart with a 0.5 mm nozzle give 12 sub-regions; 0.2 mm in 0.3 mm gives 1."""
    assert band_count(6.0, 0.5) == 12
    assert band_count(6.0, 0.2) == 30
    assert band_count(0.2, 0.3) == 1


def test_subregion_index_spans_one_to_count():
    """k = floor(r N_R) + 1 clipped to 1..N_R: r = 0 is sub-region 1, r >= 1 the last."""
    assert subregion_index(np.array([0.0, 0.099, 0.1, 0.95, 1.0, 3.0]), 10).tolist() == [1, 1, 2, 10, 10, 10]


@settings(max_examples=200)
@given(st.integers(1, 6).flatmap(lambda beta: st.lists(
    st.lists(st.floats(0.0, 1e3), min_size=beta, max_size=beta), min_size=1, max_size=20)))
def test_ring_weights_sum_to_one(rows):
    """Eq. 10: weights are in [0, 1] and sum to 1 at every point, whatever the distances."""
    weights = ring_weights(np.array(rows))
    assert np.all(weights >= -1e-12) and np.all(weights <= 1 + 1e-12)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, rtol=1e-9)


@given(st.integers(2, 6), st.integers(0, 5), st.lists(st.floats(0.01, 100.0), min_size=6, max_size=6))
def test_ring_weight_is_one_on_its_ring(beta, ring, others):
    """A point on ring i (d_i = 0) has w_i = 1 and every other weight 0."""
    ring = ring % beta
    d = np.array(others[:beta])
    d[ring] = 0.0
    weights = ring_weights(d[None, :])[0]
    assert weights[ring] == 1.0
    assert np.all(np.delete(weights, ring) == 0.0)


@given(st.lists(st.lists(st.floats(0.05, 50.0), min_size=4, max_size=4), min_size=1, max_size=10))
def test_ring_weights_equal_the_product_formula(rows):
    """ring_weights equals eq. 10 written literally with products of distances (moderate values)."""
    d = np.array(rows)
    others = np.stack([np.prod(np.delete(d, i, axis=1), axis=1) for i in range(d.shape[1])], axis=1)
    np.testing.assert_allclose(ring_weights(d), others / others.sum(axis=1, keepdims=True), rtol=1e-9)


def test_ring_weights_symmetric_cases():
    """Equal distances give equal weights; two rings give w = (d2, d1) / (d1 + d2); the weights
    follow a permutation of the rings; the nearer ring weighs more."""
    np.testing.assert_allclose(ring_weights(np.full((1, 4), 3.0)), 0.25)
    np.testing.assert_allclose(ring_weights(np.array([[1.0, 3.0]])), [[0.75, 0.25]])
    d = np.array([[1.0, 2.0, 4.0]])
    w = ring_weights(d)
    np.testing.assert_allclose(ring_weights(d[:, [2, 0, 1]]), w[:, [2, 0, 1]])
    assert w[0, 0] > w[0, 1] > w[0, 2]
    # eq. 10 equals inverse-distance weighting: w_i proportional to 1 / d_i
    np.testing.assert_allclose(w, (1 / d) / (1 / d).sum(), rtol=1e-12)


def test_region_spec_refuses_bad_values():
    """A non-positive nozzle or depth, an unknown direction or a zero count is an InputError naming the option."""
    with pytest.raises(InputError, match="--nozzle"):
        RegionSpec(nozzle_mm=0.0)
    with pytest.raises(InputError, match="--depth"):
        RegionSpec(depth_mm=-1.0)
    with pytest.raises(InputError, match="--direction"):
        RegionSpec(direction="sideways")
    with pytest.raises(InputError, match="--offsets"):
        RegionSpec(count=0)


def assert_bands_follow_the_exact_distance(ring: np.ndarray, grid: Grid, nozzle: float, limit_px: float = 1.0) -> None:
    """The one-ring family of ``ring`` labels every solid pixel with the sub-region of its exact distance to
    the ring (shapely), except pixels within ``limit_px`` of a band boundary (:func:`assert_within_one_pixel`)."""
    points, offsets, area, parent = layer(ring)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=nozzle))
    x, y = pixel_centres(grid, field.box)
    scale = field.layout.count / field.layout.length_mm
    s = scale * shapely.distance(shapely.points(x, y), shapely.LinearRing(ring))
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, field.layout.count)
    assert_within_one_pixel(k, expected, s, mask, slope_px=scale * PX, limit_px=limit_px)


def test_annulus_matches_analytic_field_and_eq8_count():
    """Concentric rings 6 mm apart, 0.49 mm nozzle: N_R = 12 (eq. 8) and every pixel's sub-region is
    floor(12 (R - rho) / (R - r0)) + 1, the analytic r = d_o / (d_o + d_i), within one pixel."""
    points, offsets, area, parent = layer(circle(10.0), circle(4.0, clockwise=True))
    grid = grid_around(10.5)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.49))
    assert field.layout.count == 12
    assert field.layout.length_mm == pytest.approx(6.0, abs=1e-3)
    x, y = pixel_centres(grid, field.box)
    rho = np.hypot(x, y)
    s = 12 * (10.0 - rho) / 6.0
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, 12)
    assert_within_one_pixel(k, expected, s, mask, slope_px=12 / 6.0 * PX)


def test_annulus_band_widths():
    """Each of the 12 sub-regions of the annulus (6 mm, 0.49 mm nozzle: width 6 / 12 = 0.5 mm) covers the
    analytic ring area between radii 10 - (k-1) 0.5 and 10 - k 0.5 mm, to within a pixel along its perimeter."""
    points, offsets, area, parent = layer(circle(10.0), circle(4.0, clockwise=True))
    grid = grid_around(10.5)
    k, mask, _ = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.49))
    counts = np.bincount(k[mask], minlength=13)[1:]
    outer = 10.0 - 0.5 * np.arange(12)
    expected = np.pi * (outer ** 2 - (outer - 0.5) ** 2) / PX ** 2
    tolerance = 2 * np.pi * outer * 2 / PX
    assert np.all(np.abs(counts - expected) <= tolerance)


def test_direction_out_counts_from_the_hole():
    """--direction out: r = d_i / (d_o + d_i), sub-region 1 touches the hole."""
    points, offsets, area, parent = layer(circle(10.0), circle(4.0, clockwise=True))
    grid = grid_around(10.5)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.49, direction="out"))
    x, y = pixel_centres(grid, field.box)
    s = 12 * (np.hypot(x, y) - 4.0) / 6.0
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, 12)
    assert_within_one_pixel(k, expected, s, mask, slope_px=2.0 * PX)


def test_disc_grades_to_its_centre():
    """A solid disc (no inner ring): L_S is its inradius, r = d / R, so the last sub-region is at the centre."""
    points, offsets, area, parent = layer(circle(8.0))
    grid = grid_around(8.5)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.39))
    assert field.layout.length_mm == pytest.approx(8.0, abs=0.05)
    count = field.layout.count
    assert count == 20
    x, y = pixel_centres(grid, field.box)
    s = count * (8.0 - np.hypot(x, y)) / field.layout.length_mm
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, count)
    assert_within_one_pixel(k, expected, s, mask, slope_px=count / field.layout.length_mm * PX)


def test_depth_stops_grading():
    """With a target depth of 2 mm and a 0.5 mm nozzle, N_R = 4 and everything deeper than 2 mm is sub-region 4."""
    points, offsets, area, parent = layer(circle(8.0))
    grid = grid_around(8.5)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.5, depth_mm=2.0))
    assert field.layout.count == 4
    x, y = pixel_centres(grid, field.box)
    deep = mask & (np.hypot(x, y) < 8.0 - 2.0 - PX)
    assert np.all(k[deep] == 4)
    s = 4 * (8.0 - np.hypot(x, y)) / 2.0
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, 4)
    assert_within_one_pixel(k, expected, s, mask, slope_px=2.0 * PX)


@settings(max_examples=12, deadline=None)
@given(st.sampled_from([0.05, 0.1, 0.2]), st.sampled_from([None, 20, 60]), st.floats(0.6, 2.0))
def test_shallow_depth_with_many_bands_stays_exact(nozzle, count, depth):
    """A depth-limited disc with steep bands (small nozzle, or many --offsets): every solid pixel is within
    one pixel of its exact band, also in the cells just past the depth (which may be flattened to N_R
    only when all their pixels are that deep)."""
    points, offsets, area, parent = layer(circle(6.0))
    grid = grid_around(6.5)
    spec = RegionSpec(nozzle_mm=nozzle, depth_mm=depth, count=count)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, spec)
    n = field.layout.count
    x, y = pixel_centres(grid, field.box)
    s = n * (6.0 - np.hypot(x, y)) / depth
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, n)
    assert_within_one_pixel(k, expected, s, mask, slope_px=n / depth * PX)


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


def star(points: int = 7, outer: float = 9.0, inner: float = 4.0) -> np.ndarray:
    """A concave star polygon with sharp convex and reflex corners."""
    angle = np.linspace(0.0, 2 * np.pi, 2 * points, endpoint=False)
    radius = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])


@pytest.mark.parametrize("shape", ["star", "blob"])
def test_bands_match_round_join_offsets(shape):
    """Sub-region k+1.. is exactly the inside of shapely's round-join offset buffer(-k w): pixels that
    disagree lie within one pixel of the offset's boundary, for every k (irregular, concave shapes)."""
    if shape == "star":
        ring = star()
    else:
        angle = np.linspace(0, 2 * np.pi, 300, endpoint=False)
        radius = 8 + 1.5 * np.sin(3 * angle) + 0.7 * np.cos(7 * angle + 1)
        ring = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    points, offsets, area, parent = layer(ring)
    grid = grid_around(10.0)
    spec = RegionSpec(nozzle_mm=0.3, depth_mm=3.0)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, spec)
    width = 3.0 / field.layout.count
    polygon = shapely.Polygon(ring)
    x, y = pixel_centres(grid, field.box)
    for offset in range(1, field.layout.count):
        inner = polygon.buffer(-offset * width, join_style="round", quad_segs=64)
        inside = shapely.contains_xy(inner, x, y)
        wrong = mask & (inside != (k > offset))
        if wrong.any():
            gap = shapely.distance(shapely.points(x[wrong], y[wrong]), inner.boundary)
            assert gap.max() <= PX, (offset, gap.max() / PX)


def test_two_holes_follow_eq10():
    """A disc with two holes (beta = 3 rings): r = 1 - w_outer of eq. 10 from the three ring distances,
    N_R from the shortest outer-to-hole distance; checked at every pixel within one pixel."""
    holes = [circle(2.0, 360, (-4.0, 0.0), clockwise=True), circle(1.5, 360, (4.0, 1.0), clockwise=True)]
    outer = circle(9.0, 720)
    points, offsets, area, parent = layer(outer, *holes)
    grid = grid_around(9.5)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.25))
    shortest = min(shapely.distance(shapely.LinearRing(outer), shapely.LinearRing(h)) for h in holes)
    assert field.layout.count == int(shortest / 0.25)
    x, y = pixel_centres(grid, field.box)
    where = shapely.points(x[mask], y[mask])
    d = np.column_stack([shapely.distance(where, shapely.LinearRing(r)) for r in (outer, *holes)])
    s = np.zeros(x.shape)
    s[mask] = (1.0 - ring_weights(d)[:, 0]) * field.layout.count
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, field.layout.count)
    wrong = mask & (k != expected)
    assert wrong.sum() < 0.02 * mask.sum()
    # disagreements sit on band boundaries: moving a pixel's centre by one pixel changes its expected band
    step = np.gradient(s, axis=(0, 1))
    slope = np.hypot(step[0], step[1])
    assert np.all(np.abs(s - np.rint(s))[wrong] <= 1.5 * slope[wrong] + 1e-9)


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


def test_layer_regions_labels_every_solid_pixel_once():
    """An island in a cavity of a hollow disc is a family of its own: every solid pixel gets a label of
    exactly the family whose region holds it, empty pixels none."""
    rings = (circle(9.0), circle(6.0, clockwise=True), circle(3.0))
    points, offsets, area, parent = layer(*rings)
    grid = grid_around(9.5)
    mask = solid_mask(points, offsets, grid)
    regions = layer_regions(points, offsets, area, parent, mask, grid, RegionSpec(nozzle_mm=0.5))
    assert len(regions.families) == 2
    b = regions.box
    label = regions.label
    assert np.array_equal(label > 0, mask[b[0]:b[1], b[2]:b[3]])
    x, y = pixel_centres(grid, b)
    island = np.hypot(x, y) < 3.0 - PX
    island_family = [i for i, f in enumerate(regions.families) if f.outer == 2][0]
    lo, hi = regions.base[island_family], regions.base[island_family + 1]
    assert np.all((label[island] >= lo) & (label[island] < hi))


def test_layer_label_is_base_plus_the_family_index_on_solid_pixels():
    """For a one-family layer, the label (built in place from the family's index) is base + k of an
    independently computed family_field on solid pixels, and 0 on empty ones."""
    angle = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    radius = 8 + 1.5 * np.sin(3 * angle) + 0.7 * np.cos(7 * angle + 1)
    points, offsets, area, parent = layer(np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
    grid = grid_around(10.0)
    mask = solid_mask(points, offsets, grid)
    spec = RegionSpec(nozzle_mm=0.3)
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec)
    field = family_field(points, offsets, layer_families(area, parent)[0], grid, spec)
    r0, r1, c0, c1 = regions.box
    solid = mask[r0:r1, c0:c1]
    expected = np.where(solid, field.index.astype(np.int64) + regions.base[0], 0)
    assert np.array_equal(regions.label, expected)
    assert regions.label[solid].min() == regions.base[0] + 1


def test_layer_labels_from_the_packed_mask_alone_agree_on_solid_pixels():
    """Built from the bit-packed solid mask only, the layer's labels equal those built with the bool mask on
    every solid pixel (an organ with a hole, an island in it and a nested lesion; box columns not on byte
    boundaries), the families and label bases the same."""
    organ, hole, island, lesion = (circle(9.0), circle(3.0, 240, (-3.0, -2.0), clockwise=True),
                                   circle(1.0, 120, (-3.0, -2.0)), circle(2.0, 200, (4.0, 2.0)))
    points, offsets, area, parent = layer(organ, hole, island, lesion)
    grid = grid_around(9.7)
    mask = solid_mask(points, offsets, grid)
    spec = RegionSpec(nozzle_mm=0.3)
    masked = layer_regions(points, offsets, area, parent, mask, grid, spec)
    packed = layer_regions(points, offsets, area, parent, None, grid, spec, np.packbits(mask, axis=1))
    assert packed.box == masked.box and np.array_equal(packed.base, masked.base)
    r0, r1, c0, c1 = masked.box
    solid = mask[r0:r1, c0:c1]
    assert np.array_equal(packed.label[solid], masked.label[solid])
    assert (masked.label[~solid] == 0).all() and packed.label[solid].min() > 0



ISLAND_LAYOUTS = {
    # an island well inside a hole of the plate: its box holds none of the plate's pixels
    "roomy hole": [circle(9.0), circle(4.0, 240, (-3.0, 0.0), clockwise=True), circle(1.5, 120, (-3.0, 0.0))],
    # the island's box reaches past its hole into the plate
    "tight hole": [circle(9.0), circle(2.0, 240, (-3.0, 0.0), clockwise=True), circle(1.9, 120, (-3.0, 0.0))],
    # two islands in one hole, each box holding a corner of the other island
    "crowded hole": [circle(9.0), circle(6.0, 360, (0.0, 0.0), clockwise=True), circle(1.5, 120, (-1.2, -1.2)),
                     circle(1.5, 120, (1.2, 1.2))],
    # a nested shell (a lesion) in the plate's solid: the plate's pixels fill its box
    "lesion": [circle(9.0), circle(2.0, 200, (3.0, 3.0))],
    # an island cut by the canvas's left edge (x = -7 mm in the test): its box is clipped
    "clipped island": [circle(9.0), circle(4.0, 240, (-4.5, 0.0), clockwise=True), circle(1.2, 120, (-6.5, 0.0))],
    # an island with a hole of its own holding another island; the outer island's box reaches into the plate
    "island in an island": [circle(9.0), circle(5.0, 360, clockwise=True), circle(4.0, 240),
                            circle(2.5, 180, clockwise=True), circle(1.0, 90)],
}


def island_grid(name: str) -> Grid:
    """The canvas of an ISLAND_LAYOUTS layer: 19 mm square around the origin, its left edge at x = -7 mm
    for the clipped island."""
    grid = grid_around(9.5)
    if name != "clipped island":
        return grid
    cut = int(round((-7.0 - grid.x_left) / PX))
    return Grid(width=grid.width - cut, height=grid.height, x_left=grid.x_left + cut * PX, y_top=grid.y_top,
                px=PX, py=PX)


def never_alone(points, offsets, families, *rest):
    """A stand-in for labels._alone_in_boxes under which every island rasterises its rings."""
    return [False] * len(families)


def family_membership(points, offsets, regions, grid) -> np.ndarray:
    """(rows, cols) int over the regions' box: the number of the family whose polygon (outer ring less
    its holes, shapely) holds each pixel centre, -1 where none does."""
    x, y = pixel_centres(grid, regions.box)
    owner = np.full(x.shape, -1)
    for number, family in enumerate(regions.families):
        ring = [points[offsets[loop]:offsets[loop + 1]] for loop in (family.outer, *family.holes)]
        owner[shapely.contains_xy(shapely.Polygon(ring[0], ring[1:]), x, y)] = number
    return owner


@pytest.mark.parametrize("name", sorted(ISLAND_LAYOUTS))
def test_islands_are_labelled_exactly_with_or_without_rasterising_their_rings(name, monkeypatch):
    """Every solid pixel carries a label of the family whose polygon holds it (shapely), and the labels
    are the same when every island rasterises its rings again (labels._family_mask) as when an island
    alone in its box (labels._alone_in_boxes) takes the layer's solid pixels there as its own."""
    points, offsets, area, parent = layer(*ISLAND_LAYOUTS[name])
    grid = island_grid(name)
    mask = solid_mask(points, offsets, grid)
    spec = RegionSpec(nozzle_mm=0.4)
    labelled = layer_regions(points, offsets, area, parent, None, grid, spec, np.packbits(mask, axis=1))
    solid = mask[labelled.box[0]:labelled.box[1], labelled.box[2]:labelled.box[3]]
    owner = family_membership(points, offsets, labelled, grid)
    label_family = np.searchsorted(labelled.base, labelled.label, side="right") - 1
    assert np.array_equal(label_family[solid], owner[solid])
    monkeypatch.setattr(labels, "_alone_in_boxes", never_alone)
    rasterised = layer_regions(points, offsets, area, parent, None, grid, spec, np.packbits(mask, axis=1))
    assert np.array_equal(rasterised.label[solid], labelled.label[solid])


def crossing_layouts():
    """Layers of crossing loops (separate shells that overlap; the reviews' cases), with their parents: a
    washer lying half over a tube's wall and half in its bore, holding a pin over the wall (by the
    washer's first point its parent is the bore, though it crosses it), a plate whose outer ring
    winds twice around a hole holding a pin (its own winding is 1 in the hole), and a figure-eight
    loop whose far lobe is solid inside another island's box, as a hole or in no family."""
    washer = np.roll(circle(3.0, 300, (4.5, 0.0)), 150, axis=0)  # first point (1.5, 0), in the bore
    chain = [circle(9.0), circle(4.0, 360, clockwise=True), washer, circle(1.5, 200, (5.5, 0.0), clockwise=True),
             circle(0.5, 90, (5.5, 0.0))]
    points, offsets, area, parent = layer(*chain)
    yield "washer over a wall", (points, offsets, area, parent)
    twice = np.concatenate([circle(9.0), circle(8.8)])
    points, offsets, area, _ = layer(twice, circle(4.0, 360, clockwise=True), circle(1.0, 120))
    yield "plate wound twice", (points, offsets, area, np.array([-1, 0, 1]))
    # a figure-eight hole of an island in the bore: a clockwise lobe in the island, a small counter-clockwise
    # one (solid) beside the other island, far from its own family's box; then the same loop with no family
    lobe_a = np.roll(circle(1.0, 120, (-3.0, 0.0), clockwise=True), 1, axis=0)  # from (-2, 0) clockwise
    lobe_b = np.roll(circle(0.15, 60, (2.3, 1.2)), 30, axis=0)
    eight = np.concatenate([lobe_a, lobe_b])
    rings = [circle(9.0), circle(6.0, 720, clockwise=True), circle(1.5, 240, (-3.0, 0.0)), eight,
             circle(1.5, 240, (3.5, 0.0))]
    points, offsets, _, _ = layer(*rings)
    area = np.array([0.5 * np.sum(r[:, 0] * np.roll(r[:, 1], -1) - np.roll(r[:, 0], -1) * r[:, 1]) for r in rings])
    yield "figure-eight hole", (points, offsets, area, np.array([-1, 0, 1, 2, 1]))
    yield "figure-eight loop of no family", (points, offsets, area, np.array([-1, 0, 1, 1, 1]))


def test_islands_over_crossing_loops_are_labelled_as_by_rasterising_their_rings(monkeypatch):
    """Where loops cross, an island takes the solid pixels of its box as its own only if the layer's other loops
    wind at most 0 times around all of them: its labels are those of rasterising its rings, on every solid
    pixel."""
    for name, (points, offsets, area, parent) in crossing_layouts():
        grid = grid_around(9.5)
        mask = solid_mask(points, offsets, grid)
        spec = RegionSpec(nozzle_mm=0.4)
        labelled = layer_regions(points, offsets, area, parent, mask, grid, spec)
        with monkeypatch.context() as patched:
            patched.setattr(labels, "_alone_in_boxes", never_alone)
            rasterised = layer_regions(points, offsets, area, parent, mask, grid, spec)
        solid = mask[labelled.box[0]:labelled.box[1], labelled.box[2]:labelled.box[3]]
        assert np.array_equal(rasterised.label[solid], labelled.label[solid]), name


def test_only_islands_alone_in_their_box_skip_rasterising_their_rings(monkeypatch):
    """The island of a roomy hole, the inner island of an island in an island and an island clipped by the
    canvas take the solid pixels of their box as theirs; an island whose box reaches into the plate, two
    islands each reaching into the other's box, the hollow island (its own island and the plate reach into
    its box) and a lesion in the plate's solid rasterise their rings."""
    rasterised = []
    real = labels._family_mask
    monkeypatch.setattr(labels, "_family_mask",
                        lambda points, offsets, family, *rest: rasterised.append(family.outer)
                        or real(points, offsets, family, *rest))
    expected = {"roomy hole": [], "tight hole": [2], "crowded hole": [2, 3], "island in an island": [2],
                "clipped island": [], "lesion": [1]}
    for name, rings in ISLAND_LAYOUTS.items():
        rasterised.clear()
        points, offsets, area, parent = layer(*rings)
        grid = island_grid(name)
        mask = solid_mask(points, offsets, grid)
        layer_regions(points, offsets, area, parent, mask, grid, RegionSpec(nozzle_mm=0.4))
        assert rasterised == expected[name], name

def rough_outline(seed: int, count: int = 900, radius: float = 6.0, amplitude: float = 0.6,
                  modes: int = 40) -> np.ndarray:
    """(count, 2) a star-shaped outline whose radius is a random sum of ``modes`` harmonics (mm): many
    shallow bumps, each a local minimum of the distance along the ring seen from inside."""
    rng = np.random.default_rng(seed)
    draws = np.array([(rng.normal(), rng.uniform(0.0, 2 * np.pi)) for _ in range(modes)])
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    mode = np.arange(2, modes + 2)[:, None]
    radius = radius + np.sum(amplitude * draws[:, :1] / (1 + mode / 4) * np.cos(mode * angle + draws[:, 1:]), axis=0)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])


@pytest.mark.parametrize("shape", ["star24", "rough100", "rough102", "rough104", "smooth6"])
def test_bands_follow_the_exact_distance_where_nearest_edges_are_far_apart(shape):
    """Every solid pixel's sub-region is the one of its exact distance to the ring (shapely), except pixels
    within one pixel of a band boundary, and none beyond: in shapes whose medial region sees many nearly
    equidistant edges (a star's deep reflex corners, an outline's bumps) the nearest edge of a pixel, or of
    a lattice centre, can lie between the edges nearest to the centres around it, where a walk along the
    ring from those stops at a local minimum (it did, up to 2.4 px off; 'smooth6' through a lattice centre)."""
    if shape.startswith("star"):
        ring = star(int(shape[4:]), 6.0, 1.5)
    elif shape.startswith("rough"):
        ring = rough_outline(int(shape[5:]))
    else:
        ring = rough_outline(int(shape[6:]), count=400, amplitude=0.3, modes=12)
    assert_bands_follow_the_exact_distance(ring, grid_around(float(np.abs(ring).max()) + 0.5), 0.2)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_rings_apart_is_shapely_distance(seed):
    """L_S between an outer ring and the holes inside it is shapely's distance between the rings (to float32
    rounding of a few hundredths of a micrometre), wherever the closest pair lies (vertex or edge)."""
    from heoslice.grading.search import rings_apart

    rng = np.random.default_rng(seed)
    outer = rough_outline(int(rng.integers(0, 2 ** 31)), count=int(rng.integers(20, 400)), radius=10.0)
    holes = [circle(float(rng.uniform(0.3, 1.5)), int(rng.integers(3, 60)), center=tuple(rng.uniform(-3, 3, 2)),
                    clockwise=True) for _ in range(int(rng.integers(1, 3)))]
    holes = [h for i, h in enumerate(holes)
             if all(shapely.Polygon(h).disjoint(shapely.Polygon(other)) for other in holes[:i])]
    points, offsets, _, _ = layer(outer, *holes)
    expected = shapely.distance(shapely.LinearRing(outer), shapely.MultiLineString([np.vstack([h, h[:1]]) for h in holes]))
    outer_set, holes_set = ring_set(points, offsets, (0,), True), ring_set(points, offsets, range(1, len(holes) + 1), False)
    assert rings_apart(outer_set, holes_set) == pytest.approx(expected, abs=1e-5)


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


@pytest.mark.parametrize("radius", [0.05, 0.12, 0.3])
def test_family_smaller_than_a_cell_is_labelled_like_its_pixels(radius):
    """A family smaller than one lattice cell (a pin a few pixels across) still labels exactly its solid
    pixels, each with its band by the exact distance to the ring (within one pixel)."""
    points, offsets, area, parent = layer(circle(radius, 64, (0.37, -0.21)))
    grid = grid_around(1.0)
    mask = solid_mask(points, offsets, grid)
    spec = RegionSpec(nozzle_mm=0.02)
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec)
    r0, r1, c0, c1 = regions.box
    solid = mask[r0:r1, c0:c1]
    assert mask.sum() == solid.sum() > 0
    assert np.array_equal(regions.label > 0, solid)
    field = regions.fields[0]
    count = field.layout.count
    x, y = pixel_centres(grid, regions.box)
    d = shapely.distance(shapely.points(x, y), shapely.LinearRing(circle(radius, 64, (0.37, -0.21))))
    s = count * d / field.layout.length_mm
    expected = np.clip(np.floor(s).astype(np.int64) + 1, 1, count)
    k = regions.label.astype(np.int64) - regions.base[0]
    wrong = solid & (k != expected)
    # (a handful of pixels: no share of wrong ones to bound, only their distance to a band boundary)
    assert np.all(np.abs(k - expected)[wrong] <= 1)
    assert np.all(np.abs(s - np.rint(s))[wrong] <= count / field.layout.length_mm * PX)


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
@given(st.integers(0, 2 ** 32 - 1), st.sampled_from(["in", "out"]))
def test_skipping_blocks_off_the_family_changes_no_label(seed, direction):
    """Lattice blocks judged wholly off the family's side are not measured; labelling with every block
    measured gives the same labels at every pixel (random bumpy outlines with one or two holes)."""
    from unittest import mock

    rng = np.random.default_rng(seed)
    outer = rough_outline(int(rng.integers(0, 2 ** 31)), count=400, radius=9.0)
    holes = [circle(float(rng.uniform(0.5, 2.0)), 120, (float(x), float(y)), clockwise=True)
             for x, y in ((-3.5, rng.uniform(-2, 2)), (3.5, rng.uniform(-2, 2)))[: int(rng.integers(1, 3))]]
    points, offsets, area, parent = layer(outer, *holes)
    grid = grid_around(11.0)
    mask = solid_mask(points, offsets, grid)
    spec = RegionSpec(nozzle_mm=0.25, direction=direction)
    culled = layer_regions(points, offsets, area, parent, mask, grid, spec)
    never_far = lattice_module._far_side
    with mock.patch.object(lattice_module, "_far_side", lambda *args: np.zeros_like(never_far(*args))):
        full = layer_regions(points, offsets, area, parent, mask, grid, spec)
    assert np.array_equal(culled.label, full.label)


def random_holes(rng: np.random.Generator, count: int, outer: np.ndarray) -> list[np.ndarray]:
    """Up to ``count`` clockwise holes (circles and bumpy blobs, 0.4-2 mm) inside ``outer``, at least
    0.3 mm from it and from each other."""
    polygon, holes, placed = shapely.Polygon(outer), [], []
    for _ in range(40 * count):
        if len(holes) == count:
            break
        radius = float(rng.uniform(0.4, 2.0))
        centre = rng.uniform(-7.0, 7.0, 2)
        disc = shapely.Point(centre).buffer(radius + 0.3)
        if not polygon.contains(disc) or any(disc.intersects(other) for other in placed):
            continue
        if rng.random() < 0.5:
            ring = circle(radius, 180, tuple(centre), clockwise=True)
        else:
            ring = rough_outline(int(rng.integers(0, 2 ** 31)), count=160, radius=radius, amplitude=0.1 * radius,
                                 modes=6)[::-1] + centre
        holes.append(ring)
        placed.append(disc)
    return holes


def assert_many_holes_follow_eq10(seed: int, hole_count: int, nozzle: float, direction: str,
                                  limit_px: float = 1.0) -> None:
    """A bumpy outline with ``hole_count`` holes: every solid pixel's sub-region is the one of the exact
    eq. 10 field from shapely's distances to every ring ('in': r = 1 - w_outer over all beta rings;
    'out': r = d_holes / (d_holes + d_outer)), except pixels within ``limit_px`` of a band boundary,
    and none off by more than one band."""
    rng = np.random.default_rng(seed)
    outer = rough_outline(int(rng.integers(0, 2 ** 31)), count=400, radius=9.0)
    holes = random_holes(rng, hole_count, outer)
    points, offsets, area, parent = layer(outer, *holes)
    grid = grid_around(11.0)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=nozzle,
                                                                                     direction=direction))
    x, y = pixel_centres(grid, field.box)
    where = shapely.points(x[mask], y[mask])
    d = np.column_stack([shapely.distance(where, shapely.LinearRing(r)) for r in (outer, *holes)])
    n = field.layout.count
    if direction == "in":
        r = 1.0 - ring_weights(d)[:, 0]
    else:
        nearest_hole = d[:, 1:].min(axis=1)
        r = nearest_hole / (nearest_hole + d[:, 0])
    s = np.full(x.shape, np.nan)
    s[mask] = r * n
    expected = np.clip(np.floor(np.nan_to_num(s)).astype(np.int64) + 1, 1, n)
    rows, cols = np.gradient(s)
    slope_px = np.hypot(rows, cols)
    wrong = mask & (k != expected)
    assert np.all(np.abs(k - expected)[wrong] <= 1)
    # a disagreeing pixel's exact s is within one pixel's step of a boundary (the slope taken where it is
    # known on both sides; at the outline, one-sided)
    distance_px = np.abs(s - np.rint(s))[wrong] / np.nan_to_num(slope_px[wrong], nan=np.inf)
    assert np.all(distance_px <= limit_px), distance_px.max()


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 6), st.sampled_from([0.15, 0.25, 0.4]),
       st.sampled_from(["in", "out"]))
def test_many_holes_follow_eq10_at_every_pixel(seed, hole_count, nozzle, direction):
    """Fitted on the lattice, a bumpy outline with up to six holes follows the exact eq. 10 field within one
    pixel (:func:`assert_many_holes_follow_eq10`). The outline touches the lattice's border and the bands
    near it are a few pixels wide, so cells there are checked against neighbours outside the family, where
    eq. 10's field is continued across the rings."""
    assert_many_holes_follow_eq10(seed, hole_count, nozzle, direction)


@settings(max_examples=5, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4), st.sampled_from(["in", "out"]))
def test_exact_per_pixel_families_follow_eq10_to_rounding(seed, hole_count, direction):
    """The path small families take (every pixel's exact distance to every ring, no lattice fit) gives every
    solid pixel the exact eq. 10 sub-region, up to float32 rounding: any pixel off lies within 0.01 px of a
    band boundary."""
    with exact_per_pixel():
        assert_many_holes_follow_eq10(seed, hole_count, 0.25, direction, limit_px=0.01)


@pytest.mark.parametrize("ring", ["notched", "star", "rough"])
def test_exact_per_pixel_bands_are_the_exact_distances(ring):
    """On the exact per-pixel path, a notched disc, a star and a rough outline label every solid pixel with the
    sub-region of its exact distance to the outline, up to float32 rounding (0.01 px)."""
    shape = {"notched": notched_circle, "star": lambda: star(24, 6.0, 1.5), "rough": lambda: rough_outline(104)}[ring]()
    with exact_per_pixel():
        assert_bands_follow_the_exact_distance(shape, grid_around(float(np.abs(shape).max()) + 0.5), 0.1,
                                               limit_px=0.01)


@pytest.mark.parametrize("direction", ["in", "out"])
def test_a_plate_of_pores_follows_eq10_at_every_pixel(direction):
    """A scaffold-like plate pierced by a 4 x 4 grid of round pores 1 mm apart (every pore coupled to every
    pixel by eq. 10, most of them far from any one cell, where per-cell quadratics of their distances
    stand in for measuring them) labels every solid pixel like shapely's exact eq. 10, except within one
    pixel of a band boundary."""
    pores = [circle(1.0, 128, (3.0 * i, 3.0 * j), clockwise=True) for i in range(4) for j in range(4)]
    plate = np.array([[-2.0, -2.0], [11.0, -2.0], [11.0, 11.0], [-2.0, 11.0]])
    points, offsets, area, parent = layer(plate, *pores)
    grid = Grid(width=340, height=340, x_left=-2.6, y_top=11.6, px=PX, py=PX)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.1, direction=direction))
    x, y = pixel_centres(grid, field.box)
    where = shapely.points(x[mask], y[mask])
    d = np.column_stack([shapely.distance(where, shapely.LinearRing(r)) for r in (plate, *pores)])
    if direction == "in":
        r = 1.0 - ring_weights(d)[:, 0]
    else:
        r = d[:, 1:].min(axis=1) / (d[:, 1:].min(axis=1) + d[:, 0])
    s = np.full(x.shape, np.nan)
    s[mask] = r * field.layout.count
    expected = np.clip(np.floor(np.nan_to_num(s)).astype(np.int64) + 1, 1, field.layout.count)
    rows, cols = np.gradient(s)
    assert_within_one_pixel(k, expected, np.nan_to_num(s), mask, np.nan_to_num(np.hypot(rows, cols), nan=np.inf))


def rectangle_with_a_row_of_holes(gap: float = 0.093, radius: float = 0.41, spacing: float = 1.07,
                                  turn: float = 1.14) -> list[np.ndarray]:
    """An 8 x 4 mm rectangle (turned by ``turn`` rad) with a row of clockwise circular holes ``gap`` mm
    inside its upper edge: eq. 10's continuation outside that edge meets a pole (d_m + d_start A = 0,
    :func:`heoslice.grading.field._band_coordinate`) about ``gap`` mm off the family, within a lattice cell."""
    outer = np.asarray(shapely.box(-4.0, -2.0, 4.0, 2.0).segmentize(0.05).exterior.coords)[:-1]
    if not shapely.LinearRing(outer).is_ccw:
        outer = outer[::-1]
    centres = np.arange(-3.5 + radius, 3.7 - radius, spacing)
    holes = [circle(radius, 90, (float(x), 2.0 - gap - radius), clockwise=True) for x in centres]
    turning = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    return [ring @ turning.T for ring in [outer, *holes]]


@pytest.mark.parametrize("count", [None, 20])
def test_cells_beside_a_pole_of_eq10_get_labels_of_the_exact_field(count):
    """Every solid pixel of a family whose eq. 10 continuation is NaN (past a pole) next to its border
    cells gets a sub-region in 1..N_R, the exact eq. 10 one (shapely distances) except within one pixel of
    a band boundary. A border cell with a NaN neighbour gets a NaN Hessian (central differences of the
    neighbour's NaN gradient); the fit test must not take that quadratic as a fit (it did, and its pixels
    were labelled 0, i.e. empty, in layer_regions)."""
    rings = rectangle_with_a_row_of_holes()
    points, offsets, area, parent = layer(*rings)
    grid = grid_around(4.6)
    spec = RegionSpec(nozzle_mm=0.25, count=count)
    k, mask, field = field_on_mask(points, offsets, area, parent, grid, spec)
    n = field.layout.count
    assert np.all((k[mask] >= 1) & (k[mask] <= n)), np.unique(k[mask])
    x, y = pixel_centres(grid, field.box)
    where = shapely.points(x[mask], y[mask])
    d = np.column_stack([shapely.distance(where, shapely.LinearRing(r)) for r in rings])
    s = np.full(x.shape, np.nan)
    s[mask] = (1.0 - ring_weights(d)[:, 0]) * n
    expected = np.clip(np.floor(np.nan_to_num(s)).astype(np.int64) + 1, 1, n)
    wrong = mask & (k != expected)
    assert np.all(np.abs(k - expected)[wrong] <= 1)
    rows, cols = np.gradient(s)
    distance_px = np.abs(s - np.rint(s))[wrong] / np.nan_to_num(np.hypot(rows, cols)[wrong], nan=np.inf)
    assert np.all(distance_px <= 1.0), distance_px.max()
    labels = layer_regions(points, offsets, area, parent, solid_mask(points, offsets, grid), grid, spec)
    b = labels.box
    assert np.all(labels.label[solid_mask(points, offsets, grid)[b[0]:b[1], b[2]:b[3]]] > 0)


def notched_circle(radius: float = 3.0, depth: float = 0.06, width: float = 0.04, count: int = 16,
                   seed: int = 2) -> np.ndarray:
    """(p, 2) a circle with ``count`` small triangular notches (``depth`` x ``width`` mm, a pixel or two)
    cut inwards at random angles: features smaller than a lattice cell that no cell centre may see."""
    rng = np.random.default_rng(seed)
    shape = shapely.Point(0.0, 0.0).buffer(radius, 256)
    for angle in rng.uniform(0.0, 2 * np.pi, count):
        out = np.array([np.cos(angle), np.sin(angle)])
        across = np.array([-out[1], out[0]]) * width / 2
        shape = shape.difference(shapely.Polygon([1.01 * radius * out + across, 1.01 * radius * out - across,
                                                  (radius - depth) * out]))
    ring = np.asarray(shape.exterior.coords)[:-1]
    return ring if shapely.LinearRing(ring).is_ccw else ring[::-1]


@pytest.mark.parametrize("exact", [False, True])
def test_rings_with_repeated_points_are_labelled_like_without_them(exact):
    """A ring whose points repeat (zero-length edges, as a mesh with doubled vertices slices into) and a hole
    with a run of nine equal points label every pixel as the same rings without the repeats do, on the
    lattice and on the exact per-pixel path (the lattice's edge seeds divided 0 by 0 on such an edge)."""
    outer, hole = circle(6.0, 300), circle(2.0, 120, (1.0, 0.5), clockwise=True)
    doubled = np.repeat(outer, np.where(np.arange(len(outer)) % 7 == 0, 2, 1), axis=0)
    stuck = np.concatenate([hole[:40], np.repeat(hole[40:41], 8, axis=0), hole[40:]])
    grid = grid_around(6.5)
    labels = []
    for rings in ((outer, hole), (doubled, stuck)):
        points, offsets, area, parent = layer(*rings)
        with exact_per_pixel() if exact else contextlib.nullcontext():
            labels.append(field_on_mask(points, offsets, area, parent, grid, RegionSpec(nozzle_mm=0.25))[:2])
    (clean, mask), (repeated, _) = labels
    assert np.array_equal(clean[mask], repeated[mask])


def slotted_circle(radius: float, count: int = 15, width_px: float = 2.0, depth_px: float = 1.0,
                   seed: int = 1098) -> np.ndarray:
    """(p, 2) a circle with ``count`` rectangular slots ``width_px`` pixels wide and ``depth_px`` deep cut
    inwards at random angles (their corners are the ring's vertices; no lattice centre may see them)."""
    shape = shapely.Point(0.0, 0.0).buffer(radius, 256)
    width, depth = width_px * PX, depth_px * PX
    for angle in np.random.default_rng(seed).uniform(0.0, 2 * np.pi, count):
        out = np.array([np.cos(angle), np.sin(angle)])
        across = np.array([-out[1], out[0]]) * width / 2
        shape = shape.difference(shapely.Polygon([1.05 * radius * out + across, 1.05 * radius * out - across,
                                                  (radius - depth) * out - across, (radius - depth) * out + across]))
    ring = np.asarray(shape.exterior.coords)[:-1]
    return ring if shapely.LinearRing(ring).is_ccw else ring[::-1]


@pytest.mark.parametrize("radius", [1.8, 2.5])
def test_slots_smaller_than_a_cell_beside_a_round_outline_move_the_bands_near_them(radius):
    """On a disc a few millimetres across (its outline turns ~5-8 degrees from cell to cell, so cells beside
    it may keep a quadratic that follows the turn), slots two pixels wide and one deep still move the first
    bands to within one pixel of the exact distance (shapely): the quadratic is kept only where it gives s
    = 0 at the outline's vertices around the cell, and a slot's corners are vertices (without that check a
    pixel came out 1.015 px from its boundary at r = 2.5 mm)."""
    ring = slotted_circle(radius)
    low, high = ring.min(axis=0) - 0.3, ring.max(axis=0) + 0.3
    size = int(np.ceil((high[0] - low[0]) / PX))
    grid = Grid(width=size, height=size, x_left=float(low[0]), y_top=float(high[1]), px=PX, py=PX)
    assert_bands_follow_the_exact_distance(ring, grid, 0.12)


def test_notches_smaller_than_a_cell_move_the_bands_near_them():
    """Every solid pixel of a disc with notches a pixel or two deep has the sub-region of its exact distance
    to the outline (shapely), except pixels within one pixel of a band boundary: a notch moves the first
    band boundaries by up to its depth around it, which a plane or quadratic fitted to the lattice centres
    does not see (cells on the outline were refined by the turn rule before eq. 10's continuation; since,
    labels came out up to 1.4 px off beside three notches)."""
    assert_bands_follow_the_exact_distance(notched_circle(), grid_around(3.5), 0.1)


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


def test_a_one_subregion_family_measures_its_lattice_only_when_its_nearest_points_are_asked_for():
    """With one sub-region (k = 1 throughout) a lattice family's field measures nothing of its rings until
    ``nearest()`` is called; then what it gives is the eagerly measured field's of a two-sub-region spec on
    the same lattice (the same starting rings' feet and edges), and the measures are kept for the next layer."""
    ring = circle(4.0, 211)
    points, offsets, area, parent = layer(ring)
    family, grid = layer_families(area, parent)[0], grid_around(4.5)
    memo = RingMemo()
    lazy = family_field(points, offsets, family, grid, RegionSpec(count=1), memo=memo)
    assert lazy.layout.count == 1 and (lazy.index == 1).all()
    measured_before = [key for key in memo.now if len(key) == 2 and isinstance(key[1], lattice_module.Lattice)]
    assert measured_before == []
    foot, edge = lazy.nearest()
    assert any(len(key) == 2 and isinstance(key[1], lattice_module.Lattice) for key in memo.now)
    eager = family_field(points, offsets, family, grid, RegionSpec(count=2))
    assert eager.lattice == lazy.lattice
    eager_foot, eager_edge = eager.nearest()
    np.testing.assert_array_equal(foot, eager_foot)
    np.testing.assert_array_equal(edge, eager_edge)


def with_points_on_its_edges(ring: np.ndarray, rng, start: int) -> np.ndarray:
    """``ring`` with a point put at a random place on every edge, starting ``start`` points on (a slice of an
    extruded wall: a plane crossing each quad's diagonal at its own height)."""
    following = np.roll(ring, -1, axis=0)
    between = ring + rng.uniform(0.05, 0.95, (len(ring), 1)) * (following - ring)
    return np.roll(np.column_stack([ring, between]).reshape(-1, 2), -start, axis=0)


def test_layers_of_an_extruded_part_reuse_the_fields_of_families_they_share(monkeypatch):
    """Layer after layer with the same vertices (the straight points moved, the rings starting elsewhere, other
    material fractions at the points), the droplet masks and RGBA images with ``cache`` are those measured
    afresh, and no family is measured again but the outermost on a stretch's second layer (the first layer's
    labels were painted over its index: a layer unlike the last keeps no outermost field); a hole moved by a
    nanometre has its family measured again, the island beside it not; on a layer whose rings all change
    nothing of the previous layer is kept; a shell inside the plate moved leaves no label behind in the
    plate's reused field."""
    from heoslice.grading import droplet_planes

    plate = np.array([[-9.0, -6.0], [9.0, -6.0], [9.0, 6.0], [-9.0, 6.0]])
    holes = [circle(2.5, 96, (-4.0, 0.0), clockwise=True), circle(2.0, 80, (3.5, 1.0), clockwise=True)]
    island = circle(1.0, 64, (-4.0, 0.0))
    grid = grid_around(9.5)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("linear"), Material("green", (0, 255, 0)),
                     None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    measured = []
    original = labels.family_field
    monkeypatch.setattr(labels, "family_field", lambda *args, **kwargs: measured.append(1) or original(*args,
                                                                                                         **kwargs))
    rng = np.random.default_rng(5)
    cache = GradingCache()
    cache_rgba = GradingCache()  # render_graded's own: its outermost family, labelled on the mask, is never kept

    def both(rings, index):
        points, offsets, area, parent = layer(*(with_points_on_its_edges(ring, rng, int(rng.integers(0, 9)))
                                                for ring in rings))
        packed = np.packbits(solid_mask(points, offsets, grid), axis=1)
        material = rng.uniform(0, 1, len(points))
        args = (points, offsets, area, parent, None, None, grid, spec, index)
        before = len(measured)
        kept = droplet_planes(*args, point_material=material, packed=packed, cache=cache)
        count = len(measured) - before
        assert np.array_equal(kept, droplet_planes(*args, point_material=material, packed=packed))
        mask = np.unpackbits(packed, axis=1, count=grid.width).view(bool)
        rgba = (points, offsets, area, parent, None, mask, grid, spec, index)
        assert np.array_equal(render_graded(*rgba, point_material=material, cache=cache_rgba).image,
                              render_graded(*rgba, point_material=material).image)
        return count

    assert both([plate, *holes, island], 0) == 2
    assert both([plate, *holes, island], 1) == 1
    assert both([plate, *holes, island], 2) == 0
    assert both([plate, *holes, island], 3) == 0
    assert both([plate, holes[0], holes[1] + [1e-6, 0.0], island], 4) == 1
    assert both([plate + 0.5, holes[0] + 0.5, holes[1] + 0.5, island + 0.5], 5) == 2
    assert len(cache.fields) == 1  # the last layer's island only: its plate's index became its labels
    # a shell inside the plate's solid paints over the plate's labels: moved, it must leave none behind
    lesion = circle(1.2, 64, (4.0, -3.5))
    assert both([plate, *holes, lesion], 6) == 2
    assert both([plate, *holes, lesion + [0.0, 0.4]], 7) == 2
    assert both([plate, *holes, lesion + [0.0, 0.8]], 8) == 1


def test_rings_that_stay_give_their_last_centres_only_for_the_same_blocks_wanted(monkeypatch):
    """Through a cavity (one hole of a plate growing and shrinking from layer to layer, the other hole staying),
    the plate's field measured with what the last layer measured equals the field measured afresh; the rings
    that stay have their centres measured again only when the blocks wanted change (the big hole's deep
    inside drops blocks), and not at all on a layer like the last."""
    from heoslice.grading import lattice as compiled

    measured = []
    original = compiled.signed_feet
    monkeypatch.setattr(compiled, "signed_feet", lambda *args: measured.append(1) or original(*args))
    plate = np.array([[-12.0, -9.0], [12.0, -9.0], [12.0, 9.0], [-12.0, 9.0]])
    stay = circle(2.0, 96, (-7.0, 0.0), clockwise=True)
    grid = grid_around(12.5)
    spec = RegionSpec(nozzle_mm=0.3)
    before: dict = {}
    counts = []
    for radius in [1.0, 2.0, 6.5, 5.5, 2.0, 2.0]:
        points, offsets, area, parent = layer(plate, stay, circle(radius, 128, (4.0, 0.0), clockwise=True))
        family = layer_families(area, parent)[0]
        memo = RingMemo(before=before)
        start = len(measured)
        kept = family_field(points, offsets, family, grid, spec, memo=memo)
        counts.append(len(measured) - start)
        assert np.array_equal(kept.index, family_field(points, offsets, family, grid, spec).index)
        before = memo.now
    assert counts == [3, 1, 3, 3, 1, 0]


def test_ring_geometry_of_several_loop_sets_is_each_sets_edges():
    """The keys of several sets of loops taken in one pass are, set by set, the bytes of the edges that
    ring_edges keeps for that set alone (its straight points left out), whatever the sets' order."""
    rng = np.random.default_rng(11)
    plate = with_points_on_its_edges(np.array([[-9.0, -6.0], [9.0, -6.0], [9.0, 6.0], [-9.0, 6.0]]), rng, 3)
    holes = [circle(2.5, 96, (-4.0, 0.0), clockwise=True), circle(2.0, 80, (3.5, 1.0), clockwise=True)]
    islands = [circle(1.0, 64, (-4.0, 0.0)), with_points_on_its_edges(circle(0.9, 12, (3.5, 1.0)), rng, 5)]
    points, offsets, _, _ = layer(plate, *holes, *islands)
    sets = [(0, 1, 2), (3,), (4,), (2, 1)]
    expected = [edges.edges_key(ring_edges(points, offsets, loops)) for loops in sets]
    assert edges.ring_geometry(points, offsets, sets) == expected
    assert edges.ring_geometry(points, offsets, sets[::-1]) == expected[::-1]
    assert edges.ring_geometry(points, offsets, []) == []


def test_a_layer_like_the_last_takes_its_labels_only_with_the_same_solid_bits_and_islands_alone():
    """The labels of a layer whose fields, solid bits and lone islands are the last layer's, itself graded
    from the fields before it (from a stretch's third layer on), are that layer's array; other solid bits, an island not alone in its box,
    the same islands listed in another order, or other fields under the same solid bits (a plate running
    off the canvas) are painted afresh, and every layer's labels equal those of a layer graded without
    ``cache``."""
    plate = np.array([[-9.0, -6.0], [9.0, -6.0], [9.0, 6.0], [-9.0, 6.0]])
    hole = circle(3.0, 96, (-3.0, 0.0), clockwise=True)
    island = circle(1.5, 64, (-3.0, 0.0))
    grid = grid_around(9.5)
    spec = RegionSpec(nozzle_mm=0.3)
    cache = GradingCache()

    def labels(rings, packed=None):
        points, offsets, area, parent = layer(*rings)
        packed = np.packbits(solid_mask(points, offsets, grid), axis=1) if packed is None else packed
        kept = layer_regions(points, offsets, area, parent, None, grid, spec, packed, cache)
        fresh = layer_regions(points, offsets, area, parent, None, grid, spec, packed)
        assert kept.box == fresh.box and np.array_equal(kept.label, fresh.label)
        return kept, packed

    first, packed = labels([plate, hole, island])
    again, _ = labels([plate, hole, island])  # the plate measured again: the first layer's labels are its index
    second, _ = labels([plate, hole, island])
    assert len({id(first.label), id(again.label), id(second.label)}) == 3  # each painted afresh
    assert labels([plate, hole, island])[0].label is second.label
    # the island's pixels cleared from the solid bits (as a caller's mask may be): painted afresh, without them
    cleared = packed.copy()
    r0, r1, c0, c1 = first.fields[1].box
    cleared[r0:r1, c0 // 8:-(-c1 // 8)] = 0
    other, _ = labels([plate, hole, island], cleared)
    assert other.label is not second.label and not np.array_equal(other.label, second.label)
    # an island near its hole's rim, so that the plate's ring meets its box: not alone, nothing is taken
    crowd = [plate, hole, circle(1.0, 64, (-1.4, 0.0))]
    crowded = [labels(crowd)[0] for _ in range(3)]
    assert crowded[2].label is not crowded[1].label
    # two islands of other sizes (other band counts) listed the other way round: the same fields, other labels
    pair = [plate, hole, circle(2.0, 64, (4.5, 0.0), clockwise=True), island, circle(0.8, 48, (4.5, 0.0))]
    for _ in range(2):
        ordered = labels(pair)[0]
    swapped = labels(pair[:3] + pair[:2:-1])[0]
    assert swapped.label is not ordered.label and not np.array_equal(swapped.label, ordered.label)
    # a plate running off the canvas, its far edge moved: the same solid bits, other fields, other labels
    near, far = (np.array([[-20.0, -6.0], [20.0, -6.0], [20.0, top], [-20.0, top]]) for top in (12.0, 16.0))
    low, high = labels([near, hole, island]), labels([far, hole, island])
    assert np.array_equal(low[1], high[1]) and not np.array_equal(low[0].label, high[0].label)


def test_a_layer_like_the_last_with_other_contour_materials_jets_its_own_choices():
    """Two layers alike but for their contour's material (uniform, 0.2 then 0.7): the second layer's droplet
    masks with ``cache`` are those graded afresh, not the first layer's choices of material."""
    from heoslice.grading import droplet_planes

    plate = np.array([[-9.0, -6.0], [9.0, -6.0], [9.0, 6.0], [-9.0, 6.0]])
    points, offsets, area, parent = layer(plate, circle(3.0, 96, (-3.0, 0.0), clockwise=True))
    grid = grid_around(9.5)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("linear"), Material("green", (0, 255, 0)),
                     None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    packed = np.packbits(solid_mask(points, offsets, grid), axis=1)
    args = (points, offsets, area, parent, None, None, grid, spec, 4)
    cache = GradingCache()
    planes = [droplet_planes(*args, point_material=np.full(len(points), share), packed=packed, cache=cache)
              for share in (0.2, 0.7)]
    assert not np.array_equal(planes[0], planes[1])
    assert np.array_equal(planes[1], droplet_planes(*args, point_material=np.full(len(points), 0.7), packed=packed))


def test_holes_that_stay_while_another_shrinks_are_measured_once(monkeypatch):
    """A plate whose big hole shrinks layer by layer (more of the lattice is wanted each time) while its outline
    and small hole stay: only the shrinking hole's lattice passes are made again, the others' are taken from
    the layer before and completed where newly wanted, and the droplet masks equal those measured afresh."""
    from heoslice.grading import droplet_planes

    plate = np.array([[-20.0, -14.0], [20.0, -14.0], [20.0, 14.0], [-20.0, 14.0]])
    small = circle(1.5, 64, (14.0, 8.0), clockwise=True)
    grid = grid_around(20.5)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("linear"), Material("green", (0, 255, 0)),
                     None, DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    passes = []
    ring_measures = field_module.ring_measures
    monkeypatch.setattr(field_module, "ring_measures", lambda *args: passes.append(1) or ring_measures(*args))
    cache = GradingCache()
    for index, radius in enumerate([11.0, 10.0, 8.5, 7.0]):
        points, offsets, area, parent = layer(plate, circle(radius, 200, (-6.0, 0.0), clockwise=True), small)
        packed = np.packbits(solid_mask(points, offsets, grid), axis=1)
        args = (points, offsets, area, parent, None, None, grid, spec, index)
        before = len(passes)
        kept = droplet_planes(*args, packed=packed, cache=cache)
        assert len(passes) - before == (3 if index == 0 else 1)
        assert np.array_equal(kept, droplet_planes(*args, packed=packed))


def test_layer_families_end_on_a_cycle_of_parents():
    """A parent array with a cycle (a broken hierarchy) gives families instead of a walk up the parents that never
    ends (an alarm fails the test rather than hanging it)."""
    import signal

    def stuck(*_):
        raise TimeoutError("layer_families did not return")

    signal.signal(signal.SIGALRM, stuck)
    signal.alarm(10)
    try:
        families = layer_families(np.array([0.759, -0.7588, 0.5]), np.array([1, 0, 2]))
    finally:
        signal.alarm(0)
    assert [family.outer for family in families] == [0, 2]


@pytest.mark.parametrize("case", [
    dict(radius=4.929553957831061, count=19, width_px=1.0810259490069523, depth_px=1.8423039142734026,
         seed=1320720311, nozzle=0.15),
    dict(radius=4.919592804775299, count=12, width_px=1.4799149950599941, depth_px=1.609244560496816,
         seed=1063433706, nozzle=0.25),
    dict(radius=5.863585269053118, count=24, width_px=1.7783848765776338, depth_px=1.5563520939222553,
         seed=1585793302, nozzle=0.15)])
def test_slotted_discs_a_centimetre_across_keep_their_bands_within_a_pixel(case):
    """Discs ~10 mm across with slots one or two pixels wide (the review's sweep): every band within a pixel of
    the exact distance. Their reflex corners crease the field, so they keep 0.5 mm cells; fitted on 0.68 mm
    cells, pixels 1.2-1.3 px from their boundary came out in the next band."""
    case = dict(case)
    nozzle = case.pop("nozzle")
    ring = slotted_circle(**case)
    low, high = ring.min(axis=0) - 0.3, ring.max(axis=0) + 0.3
    size = int(np.ceil((high[0] - low[0]) / PX))
    grid = Grid(width=size, height=size, x_left=float(low[0]), y_top=float(high[1]), px=PX, py=PX)
    assert_bands_follow_the_exact_distance(ring, grid, nozzle)


def test_only_families_of_one_or_two_convex_rings_get_the_wider_cells():
    """At 600 dpi a disc and a tube's wall (two circles) are fitted on 16-pixel cells (~0.68 mm), a disc with a
    slot, a square with a notch and a plate with two holes on 12-pixel cells (~0.5 mm)."""
    grid = grid_around(10.0)
    square = np.array([[-6.0, -6.0], [6.0, -6.0], [6.0, 6.0], [-6.0, 6.0]])
    notched = np.array([[-6.0, -6.0], [6.0, -6.0], [6.0, 6.0], [0.5, 6.0], [0.0, 5.0], [-0.5, 6.0], [-6.0, 6.0]])
    cases = {16: [(circle(6.0),), (circle(6.0), circle(3.0, 200, (1.0, 0.0), clockwise=True)), (square,)],
             12: [(slotted_circle(6.0, count=3),), (notched,),
                  (square, circle(1.0, 64, (-3.0, 0.0), clockwise=True), circle(1.0, 64, (3.0, 0.0), clockwise=True))]}
    for cell, shapes in cases.items():
        for rings in shapes:
            points, offsets, area, parent = layer(*rings)
            field = family_field(points, offsets, layer_families(area, parent)[0], grid, RegionSpec())
            assert field.lattice.cell == cell, len(rings)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(1, 4))
def test_block_bounds_are_the_distances_to_the_edges_nearest_the_block_centres(seed, rings):
    """Each block's bound is the exact distance to its edge, and that edge is the nearest to the block's centre
    (within float32 rounding of the search): never below the true distance, so every radius built on it holds
    the nearest edge, and never more than 1e-4 mm above it."""
    rng = np.random.default_rng(seed)
    edges = random_rings(rng, rings)
    lattice = lattice_module.Lattice(row0=0, col0=0, cell=8, rows=int(rng.integers(1, 120)), cols=int(rng.integers(1, 120)),
                              x0=-70.0, y0=70.0, dx=float(rng.uniform(0.3, 1.5)), dy=float(rng.uniform(0.3, 1.5)))
    bounds = lattice_module.block_bounds(edges, lattice, tree_of(edges))
    x, y = bounds.blocks.centres()
    cx, cy = np.meshgrid(x, y)
    squared = brute_squared(cx.ravel(), cy.ravel(), edges)
    exact = np.sqrt(squared.min(axis=1))
    of_edge = np.sqrt(squared[np.arange(len(exact)), bounds.edge.ravel()])
    np.testing.assert_allclose(bounds.upper.ravel(), of_edge, rtol=0, atol=1e-9)
    assert np.all(bounds.upper.ravel() >= exact - 1e-9) and np.all(bounds.upper.ravel() <= exact + 1e-4)


def test_the_distance_from_the_outer_ring_to_its_holes_is_the_least_hole_by_hole_and_kept_a_layer(monkeypatch):
    """L_S of a plate with holes, taken hole by hole, is exactly rings_apart of the outer ring and all its holes
    at once; through a cavity (one hole changing) only the changed hole's distance is measured again."""
    rng = np.random.default_rng(3)
    plate = np.array([[-12.0, -9.0], [12.0, -9.0], [12.0, 9.0], [-12.0, 9.0]])
    centres = [(-7.0, -4.0), (-7.0, 4.0), (0.0, -4.0), (0.0, 4.0)]
    holes = [circle(float(rng.uniform(1.0, 2.5)), int(rng.integers(12, 200)), c, clockwise=True) for c in centres]
    counted = []
    original = search.rings_apart
    monkeypatch.setattr(search, "rings_apart", lambda *a: counted.append(1) or original(*a))
    grid = grid_around(12.5)
    spec = RegionSpec(nozzle_mm=0.05)
    before: dict = {}
    measured = []
    for radius in [2.0, 2.6, 2.6]:
        rings = [plate, *holes, circle(radius, 96, (7.0, 0.0), clockwise=True)]
        points, offsets, area, parent = layer(*rings)
        family = layer_families(area, parent)[0]
        outer = ring_set(points, offsets, (family.outer,), True)
        everything = original(outer, ring_set(points, offsets, family.holes, False))
        memo = RingMemo(before=before)
        start = len(counted)
        field = family_field(points, offsets, family, grid, spec, memo=memo)
        assert field.layout.length_mm == everything
        measured.append(len(counted) - start)
        before = memo.now
    assert measured == [len(holes) + 1, 1, 0]


@pytest.mark.parametrize("options, message", [({"count": 10**9}, "--offsets"), ({"nozzle_mm": 1e-9}, "--nozzle"),
                                              ({"nozzle_mm": 1e308}, "--nozzle")])
def test_absurd_sub_region_options_are_refused_before_any_allocation(options, message):
    """--offsets 1e9 and --nozzle 1e-9 (7-37 GiB of bands) or 1e308 are one-line input errors in RegionSpec."""
    from heoslice.errors import InputError
    from heoslice.grading import RegionSpec

    with pytest.raises(InputError, match=message):
        RegionSpec(**options)


def test_painting_a_family_after_the_first_takes_no_copy_wider_than_the_labels(monkeypatch):
    """Two equal plates side by side (the second painted over the label array from its own index plus its label
    base): painting allocates at most the labels, the box's solid bits and one copy of the box's index in the
    labels' width, not one widened to int64 by the base (4x the index, the largest allocation of a scan layer)."""
    import tracemalloc

    square = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 8.0], [0.0, 8.0]])
    points, offsets, area, parent = layer(square - [9.0, 4.0], square + [1.0, -4.0])
    grid = grid_around(9.5)
    packed = np.packbits(solid_mask(points, offsets, grid), axis=1)
    peaks = []
    original = labels._paint_labels

    def measured(*args, **kwargs):
        tracemalloc.start()
        try:
            label = original(*args, **kwargs)
            peaks.append((tracemalloc.get_traced_memory()[1], label))
        finally:
            tracemalloc.stop()
        return label

    monkeypatch.setattr(labels, "_paint_labels", measured)
    regions = layer_regions(points, offsets, area, parent, None, grid, RegionSpec(nozzle_mm=0.3), packed)
    (peak, label), = peaks
    second = regions.fields[1]
    box_pixels = (second.box[1] - second.box[0]) * (second.box[3] - second.box[2])
    assert len(regions.fields) == 2 and label.dtype == np.int16 and box_pixels > 20_000
    assert peak <= label.nbytes + box_pixels * (1 + 2) + 64_000


def test_one_subregion_families_paint_their_label_from_one_value_without_an_index_array(monkeypatch):
    """Two plates side by side with one sub-region each (a coloured slice without grading), from the packed
    mask: each family's index is one read-only value holding no memory of its box, painting allocates at most
    the labels and the second box's solid bits (no index-sized copy), and on every solid pixel the labels are
    those of the same layer labelled from the bool mask (whose indices are whole arrays)."""
    import tracemalloc

    square = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 8.0], [0.0, 8.0]])
    points, offsets, area, parent = layer(square - [9.0, 4.0], square + [1.0, -4.0])
    grid = grid_around(9.5)
    mask = solid_mask(points, offsets, grid)
    packed = np.packbits(mask, axis=1)
    spec = RegionSpec(count=1)
    peaks = []
    original = labels._paint_labels

    def measured(*args, **kwargs):
        tracemalloc.start()
        try:
            label = original(*args, **kwargs)
            peaks.append((tracemalloc.get_traced_memory()[1], label))
        finally:
            tracemalloc.stop()
        return label

    monkeypatch.setattr(labels, "_paint_labels", measured)
    regions = layer_regions(points, offsets, area, parent, None, grid, spec, packed)
    (peak, label), = peaks
    second = regions.fields[1]
    box_pixels = (second.box[1] - second.box[0]) * (second.box[3] - second.box[2])
    assert len(regions.fields) == 2 and box_pixels > 20_000
    for field in regions.fields:
        assert field.layout.count == 1 and not field.index.flags.writeable and not any(field.index.strides)
    assert peak <= label.nbytes + box_pixels + 64_000
    masked = layer_regions(points, offsets, area, parent, mask, grid, spec)
    assert masked.box == regions.box and np.array_equal(masked.base, regions.base)
    r0, r1, c0, c1 = regions.box
    solid = mask[r0:r1, c0:c1]
    assert np.array_equal(regions.label[solid], masked.label[solid])
    assert set(np.unique(regions.label[solid])) == {regions.base[0] + 1, regions.base[1] + 1}
