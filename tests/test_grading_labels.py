"""Tests of heoslice.grading.labels: a layer's labels, islands alone in their boxes, what the last layer leaves."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from helpers import PX, circle, grid_around, layer, pixel_centres

from heoslice.grading import (
    GradeSpec,
    GradingCache,
    RegionSpec,
    edges,
    family_field,
    labels,
    layer_families,
    layer_regions,
    render_graded,
)
from heoslice.grading.edges import ring_edges
from heoslice.layers.rasterising import Grid, solid_mask
from heoslice.material import DEFAULT_MATERIALS, Material, make_function

pytestmark = pytest.mark.usefixtures("lattice_fit_for_every_family")  # conftest.py: small families on the lattice too


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


def _two_plates_painted(monkeypatch, spec: RegionSpec):
    """Two equal plates side by side labelled from the packed mask alone, with the peak of what painting their
    labels allocated: (the layer (points, offsets, area, parent), grid, bool mask, regions, peak bytes, pixels of
    the second family's box)."""
    import tracemalloc

    square = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 8.0], [0.0, 8.0]])
    loops = layer(square - [9.0, 4.0], square + [1.0, -4.0])
    grid = grid_around(9.5)
    mask = solid_mask(loops[0], loops[1], grid)
    peaks = []
    original = labels._paint_labels

    def measured(*args, **kwargs):
        tracemalloc.start()
        try:
            label = original(*args, **kwargs)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        return label

    monkeypatch.setattr(labels, "_paint_labels", measured)
    regions = layer_regions(*loops, None, grid, spec, np.packbits(mask, axis=1))
    (peak,) = peaks
    second = regions.fields[1]
    box_pixels = (second.box[1] - second.box[0]) * (second.box[3] - second.box[2])
    assert len(regions.fields) == 2 and box_pixels > 20_000
    return loops, grid, mask, regions, peak, box_pixels


def _disc_and_island(hole: float, island: float, spec: RegionSpec):
    """A disc of radius 9 mm with a hole of radius ``hole`` and an island of radius ``island`` in it, labelled
    from the packed mask (the droplet masks' path), the disc's box the layer's: (points, offsets, grid, mask,
    regions)."""
    points, offsets, area, parent = layer(circle(9.0), circle(hole, clockwise=True), circle(island))
    grid = grid_around(9.5)
    mask = solid_mask(points, offsets, grid)
    regions = layer_regions(points, offsets, area, parent, None, grid, spec, np.packbits(mask, axis=1))
    assert len(regions.families) == 2 and regions.fields[0].box == regions.box
    return points, offsets, grid, mask, regions


def test_an_outermost_family_spanning_a_layer_of_several_lends_its_index_as_the_labels():
    """A thin hollow disc (few sub-regions: uint8 would do) with a wide island in its cavity (many: uint16):
    the disc's index, kept 16 bits wide for the island's labels, is the layer's label array, painted over,
    not copied into a wider one."""
    *_, regions = _disc_and_island(8.5, 8.0, RegionSpec(nozzle_mm=0.025))
    assert regions.base[1] < 256 <= regions.label_count and regions.label.dtype == np.uint16
    assert regions.label is regions.fields[0].index


def test_an_outermost_family_of_a_layer_of_few_labels_lends_its_index_in_uint8():
    """A hollow disc of a few sub-regions and an island in its cavity at a coarse nozzle (under 256 labels in
    all): the disc's index, made as wide as the whole layer's labels need (the island's measured first), is
    the layer's uint8 label array, and every solid pixel of the island holds one of the island's labels."""
    _, _, grid, _, regions = _disc_and_island(7.5, 7.0, RegionSpec(nozzle_mm=0.3))
    assert regions.label.dtype == np.uint8 and regions.label is regions.fields[0].index
    x, y = pixel_centres(grid, regions.box)
    island = np.hypot(x, y) < 7.0 - PX
    assert np.all((regions.label[island] > regions.base[1]) & (regions.label[island] < regions.base[2]))


def test_one_subregion_families_spanning_a_layer_of_several_are_labelled_in_uint8():
    """The thin hollow disc and wide island with one sub-region each (a coloured part without grading): the
    disc's index is one value, so the labels of the two families are uint8 (the narrowest), the disc's label on
    its own solid pixels and the island's on its own."""
    points, offsets, grid, mask, regions = _disc_and_island(8.5, 8.0, RegionSpec(count=1))
    assert regions.label.dtype == np.uint8
    rows, cols = slice(*regions.box[:2]), slice(*regions.box[2:])
    disc = solid_mask(points[:offsets[2]], offsets[:3], grid)[rows, cols]
    solid = mask[rows, cols]
    assert set(np.unique(regions.label[disc]).tolist()) == {regions.base[0] + 1}
    assert set(np.unique(regions.label[solid & ~disc]).tolist()) == {regions.base[1] + 1}


def test_painting_a_family_after_the_first_takes_no_copy_wider_than_the_labels(monkeypatch):
    """Two equal plates side by side (the second painted over the label array from its own index plus its label
    base): painting allocates at most the labels, the box's solid bits and one copy of the box's index in the
    labels' width, not one widened to int64 by the base (4x the index, the largest allocation of a scan layer)."""
    _, _, _, regions, peak, box_pixels = _two_plates_painted(monkeypatch, RegionSpec(nozzle_mm=0.3))
    assert regions.label.dtype == np.uint8  # few labels, in an array of their own (the first box is not the layer's)
    assert peak <= regions.label.nbytes + box_pixels * (1 + regions.label.itemsize) + 64_000


def test_one_subregion_families_paint_their_label_from_one_value_without_an_index_array(monkeypatch):
    """Two plates side by side with one sub-region each (a coloured slice without grading), from the packed
    mask: each family's index is one read-only value holding no memory of its box, painting allocates at most
    the labels and the second box's solid bits (no index-sized copy), and on every solid pixel the labels are
    those of the same layer labelled from the bool mask (whose indices are whole arrays)."""
    spec = RegionSpec(count=1)
    loops, grid, mask, regions, peak, box_pixels = _two_plates_painted(monkeypatch, spec)
    for field in regions.fields:
        assert field.layout.count == 1 and not field.index.flags.writeable and not any(field.index.strides)
    assert peak <= regions.label.nbytes + box_pixels + 64_000
    masked = layer_regions(*loops, mask, grid, spec)
    assert masked.box == regions.box and np.array_equal(masked.base, regions.base)
    r0, r1, c0, c1 = regions.box
    solid = mask[r0:r1, c0:c1]
    assert np.array_equal(regions.label[solid], masked.label[solid])
    assert set(np.unique(regions.label[solid])) == {regions.base[0] + 1, regions.base[1] + 1}


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
