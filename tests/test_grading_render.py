"""Tests of heoslice.grading.render and eq. 8's precision: exact band colours, the rings' colours, the start
colour per pixel, and N_R of a single-precision wall."""

from __future__ import annotations

import numpy as np
import shapely

from heoslice.grading import (
    GradeSpec,
    RegionSpec,
    band_count,
    family_field,
    layer_families,
    layer_regions,
    render_graded,
)
from heoslice.grading.spec import coordinate_precision
from heoslice.layers.rasterising import Grid, contour_pixels, solid_mask
from heoslice.material import DEFAULT_MATERIALS, Material, make_function

PX = 25.4 / 600
GREEN = Material("green", (0, 255, 0))
PLY = (135.0, 50.0, 135.0)


def square(half: float, clockwise: bool = False, dtype=np.float64) -> np.ndarray:
    """(4, 2) square of half-side ``half`` mm about the origin, counter-clockwise unless ``clockwise`` (a hole)."""
    ring = np.array([[-half, -half], [half, -half], [half, half], [-half, half]], dtype=dtype)
    return ring[::-1] if clockwise else ring


def layer(*rings: np.ndarray):
    """points, offsets, signed areas and parents of one layer's rings (the first the outer, the rest its holes)."""
    points = np.concatenate(rings)
    offsets = np.concatenate([[0], np.cumsum([len(ring) for ring in rings])])
    area = np.array([shapely.LinearRing(ring).is_ccw and shapely.Polygon(ring).area or -shapely.Polygon(ring).area
                     for ring in rings])
    parent = np.array([-1] + [0] * (len(rings) - 1))
    return points, offsets, area, parent


def grid_around(half: float) -> Grid:
    """A 600 dpi grid over the square of half-side ``half`` mm about the origin."""
    size = int(np.ceil(2 * half / PX))
    return Grid(width=size, height=size, x_left=-half, y_top=half, px=PX, py=PX)


def graded_tube(direction: str):
    """A square tube (20 mm across, 5 mm wall) with the PLY colour PLY at every point, graded linearly to
    green at a 0.2 mm nozzle: (image, labels, regions, mask, points, offsets, grid)."""
    points, offsets, area, parent = layer(square(10.0), square(5.0, clockwise=True))
    grid = grid_around(10.5)
    mask = solid_mask(points, offsets, grid)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.2, direction=direction), make_function("linear"), GREEN, None,
                     DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    colors = np.tile(PLY, (len(points), 1))
    image = render_graded(points, offsets, area, parent, None, mask, grid, spec, 0, point_colors=colors).image
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec.regions)
    return image, regions, mask, points, offsets, grid


def contour_sides(mask: np.ndarray, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """(outer, inner) (k, 2) row/col of the tube's contour pixels next to its outer ring and next to its hole."""
    pixels = contour_pixels(mask)
    x = grid.x_left + (pixels[:, 1] + 0.5) * grid.px
    y = grid.y_top - (pixels[:, 0] + 0.5) * grid.py
    inner = np.maximum(np.abs(x), np.abs(y)) < 7.5
    return pixels[~inner], pixels[inner]


def test_graded_tube_reaches_the_target_exactly_in_the_last_band_and_on_the_inner_ring():
    """Graded inwards, every pixel of the last band and of the inner ring's contour is exactly (0, 255, 0)
    (no int16 overflow: it came out (1, 255, 1)); band k is exactly rint(start + (target - start) k / N_R),
    so the first band starts from the PLY colour; the outer ring's contour pixels carry the PLY colour."""
    image, regions, mask, _, _, grid = graded_tube("in")
    count = regions.fields[0].layout.count
    assert count == 25
    b = regions.box
    view = image[b[0]:b[1], b[2]:b[3], :3].astype(int)
    band = regions.label - regions.base[0]
    outer, inner = contour_sides(mask, grid)
    on_contour = np.zeros(mask.shape, bool)
    on_contour[tuple(contour_pixels(mask).T)] = True
    inside = (band >= 1) & ~on_contour[b[0]:b[1], b[2]:b[3]]
    for k in (1, 13, 14, count):
        expected = np.rint(np.array(PLY) + (np.array(GREEN.color) - np.array(PLY)) * k / count)
        assert (view[inside & (band == k)] == expected).all(), k
    assert (image[tuple(inner.T)][:, :3] == GREEN.color).all()
    assert (image[tuple(outer.T)][:, :3] == PLY).all()


def test_graded_outwards_the_inner_ring_carries_the_start_and_the_outer_ring_the_target():
    """Graded outwards (from the hole), the hole's contour pixels carry the PLY colour and the outer
    ring's, in the last band, exactly the target."""
    image, _, mask, _, _, grid = graded_tube("out")
    outer, inner = contour_sides(mask, grid)
    assert (image[tuple(inner.T)][:, :3] == PLY).all()
    assert (image[tuple(outer.T)][:, :3] == GREEN.color).all()


def bumpy_outline(count: int = 720) -> np.ndarray:
    """(count, 2) counter-clockwise outline r = 8 + 0.6 sin(7 theta), mm."""
    theta = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    radius = 8.0 + 0.6 * np.sin(7 * theta)
    return np.column_stack([radius * np.cos(theta), radius * np.sin(theta)])


def test_no_step_inside_a_band_exceeds_one_level_beyond_the_contour_colours():
    """On a bumpy outline whose points' colours vary along it, two neighbouring pixels of the same band
    differ by at most 1/255 more than the colours at their exact nearest contour points (shapely) do (and
    half a level of float32 search): the start colour is taken per pixel, not per lattice cell (which made
    steps of several levels)."""
    outline = bumpy_outline()
    points, offsets, area, parent = layer(outline)
    theta = np.arctan2(outline[:, 1], outline[:, 0])
    colors = np.column_stack([128 + 100 * np.sin(3 * theta), np.full(len(theta), 60.0), 128 + 100 * np.cos(theta)])
    grid = grid_around(9.0)
    mask = solid_mask(points, offsets, grid)
    spec = GradeSpec(RegionSpec(nozzle_mm=0.4), make_function("linear"), GREEN, None, DEFAULT_MATERIALS["M1"],
                     DEFAULT_MATERIALS["M2"])
    image = render_graded(points, offsets, area, parent, None, mask, grid, spec, 0, point_colors=colors).image
    regions = layer_regions(points, offsets, area, parent, mask, grid, spec.regions)
    count = regions.fields[0].layout.count
    b = regions.box
    label = regions.label
    rows, cols = np.indices(label.shape)
    x = grid.x_left + (cols + b[2] + 0.5) * grid.px
    y = grid.y_top - (rows + b[0] + 0.5) * grid.py
    ring = shapely.LinearRing(outline)
    along = shapely.line_locate_point(ring, shapely.points(x.ravel(), y.ravel()))
    knots = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(np.vstack([outline, outline[:1]]), axis=0).T))])
    start = np.stack([np.interp(along, knots, np.append(c, c[0])) for c in colors.T], axis=-1).reshape(*label.shape, 3)
    fraction = np.clip(label - regions.base[0], 0, count) / count
    reference = start + (np.array(GREEN.color) - start) * fraction[..., None]
    view = image[b[0]:b[1], b[2]:b[3], :3].astype(float)
    on_contour = np.zeros(mask.shape, bool)
    on_contour[tuple(contour_pixels(mask).T)] = True
    usable = (label > 0) & ~on_contour[b[0]:b[1], b[2]:b[3]]
    for axis in (0, 1):
        a = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
        c = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
        pair = usable[a] & usable[c] & (label[a] == label[c])
        step = np.abs(view[a] - view[c])[pair]
        # + 1 for rounding both pixels, + 0.5 for the float32 search near the bumps' centres of curvature, where
        # the nearest point slides along the outline for a tiny change of distance
        allowed = np.abs(reference[a] - reference[c])[pair] + 1.5
        assert (step <= allowed).all(), float((step - allowed).max())


def test_a_single_precision_wall_of_5_mm_gives_25_bands():
    """eq. 8's floor allows for the rounding of float32 coordinates: a square tube stored in float32 whose
    wall measures 4.99999976 mm gets N_R = 25 at a 0.2 mm nozzle (24 with a fixed 1e-9 tolerance); the
    same numbers in double precision are what they say."""
    outer, hole = square(7.7, dtype=np.float32), square(2.7, clockwise=True, dtype=np.float32)
    wall = float(np.float32(7.7)) - float(np.float32(2.7))
    assert wall < 5.0 and band_count(wall, 0.2) == 24
    assert band_count(wall, 0.2, coordinate_precision(outer[:, 0], outer[:, 1])) == 25
    assert band_count(wall, 0.2, coordinate_precision(np.array([7.7 + 1e-7]), np.array([0.1]))) == 24
    points, offsets, area, parent = layer(outer, hole)
    family = layer_families(area, parent)[0]
    field = family_field(points, offsets, family, grid_around(8.0), RegionSpec(nozzle_mm=0.2))
    assert field.layout.count == 25
