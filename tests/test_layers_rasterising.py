"""Tests of rasterising.py: masks at pixel centres against shapely, packed bits, grids, colours."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from helpers import contours_of, layer_loops, near_contour, winding_reference
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.layers.bits import count_solid
from heoslice.layers.rasterising import (
    Grid,
    grid_for,
    packed_mask,
    packed_mask_and_count,
    part_rows,
    render_layer,
    solid_mask,
)

MESHES = {
    "sphere": lambda: procedural.sphere(10.0, 4),
    "torus": lambda: procedural.torus(12.0, 4.0),
    "island in a hole": lambda: procedural.shell_with_island(10.0, 6.0, 2.5),
    "nested shells": lambda: procedural.nested_shells(10.0, 4.0, (3.0, 0.0, 0.0)),
    "box on planes": lambda: procedural.box((6.0, 4.0, 3.0), origin=(-3.0, -2.0, 0.0), z_cuts=(0.5, 1.5)),
    "thin wall": lambda: procedural.thin_wall(0.02, 2.0, 8.0),
}


def assert_matches_reference(points, offsets, grid):
    """Mask equals winding > 0 by shapely at every pixel centre not within 1e-6 mm of a contour."""
    mask = solid_mask(points, offsets, grid)
    x, y = grid.centres()
    xx, yy = np.meshgrid(x, y)
    reference = winding_reference(points, offsets, xx, yy) > 0
    differ = mask != reference
    if differ.any():
        assert near_contour(points, offsets, xx[differ], yy[differ]).all()
    return mask


@pytest.mark.parametrize("name", MESHES)
def test_masks_match_point_in_polygon_reference(name):
    """Every layer's mask is winding number > 0 at pixel centres (shapely reference)."""
    mesh = MESHES[name]()
    z, contours = contours_of(mesh, 0.5)
    bounds = np.array([mesh.vertices.min(axis=0)[:2], mesh.vertices.max(axis=0)[:2]])
    grid = grid_for(bounds, (254.0, 254.0), margin_mm=0.5)  # 0.1 mm pixels
    solid = 0
    for layer in range(len(z)):
        solid += assert_matches_reference(*layer_loops(contours, layer), grid).sum()
    if name == "thin wall":
        assert solid <= len(z) * 81  # at most one row of centres (8 mm / 0.1 mm + 1) fits in the wall
    else:
        assert solid > 0


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    vertices=st.integers(3, 40),
    dx=st.floats(-1.0, 1.0),
    dy=st.floats(-1.0, 1.0),
    dpi=st.floats(30.0, 400.0),
)
def test_random_star_polygons_match_reference(seed, vertices, dx, dy, dpi):
    """Random simple polygons (either orientation) at random grid offsets and resolutions."""
    rng = np.random.default_rng(seed)
    angle = np.sort(rng.uniform(0, 2 * np.pi, vertices))
    radius = rng.uniform(0.5, 5.0, vertices)
    points = np.column_stack([radius * np.cos(angle) + dx, radius * np.sin(angle) + dy])
    assume(shapely.Polygon(points).is_valid)
    if rng.random() < 0.5:
        points = points[::-1]
    grid = grid_for(np.array([[-6.0, -6.0], [6.0, 6.0]]), (dpi, dpi * rng.uniform(0.5, 2.0)))
    mask = assert_matches_reference(points, np.array([0, vertices]), grid)
    if points[:, 0] @ np.roll(points[:, 1], -1) - np.roll(points[:, 0], -1) @ points[:, 1] < 0:
        assert not mask.any()  # a lone clockwise loop has winding -1: empty


def test_packed_mask_is_packbits_of_the_mask_and_counts_match():
    """packed_mask has np.packbits layout (MSB first, padded rows) and count_solid counts its bits."""
    mesh = procedural.torus(12.0, 4.0)
    z, contours = contours_of(mesh, 1.0)
    grid = grid_for(np.array([[-17.0, -17.0], [17.0, 17.0]]), (150.0, 150.0))
    assert grid.width % 8 != 0 or grid.width  # any width works; padding bits must stay zero
    points, offsets = layer_loops(contours, len(z) // 2)
    packed = packed_mask(points, offsets, grid)
    mask = solid_mask(points, offsets, grid)
    np.testing.assert_array_equal(packed, np.packbits(mask, axis=1))
    assert count_solid(packed) == mask.sum() > 0


def crossing_rule_mask(points, offsets, grid):
    """Test reference, the crossing rule written out pixel by pixel: an edge adds its sign (+1 running down
    the image) to the winding of every pixel of each row r with v_low < r <= v_high from column
    clip(ceil(u at r), 0, width) on; solid where the winding is above 0. (h, w) bool."""
    following = np.arange(1, len(points) + 1)
    following[offsets[1:] - 1] = offsets[:-1]
    u = (points[:, 0] - grid.x_left) / grid.px - 0.5
    v = (grid.y_top - points[:, 1]) / grid.py - 0.5
    winding = np.zeros((grid.height, grid.width + 1), np.int64)
    for start, end in zip(range(len(points)), following):
        low, high = min(v[start], v[end]), max(v[start], v[end])
        dv = v[end] - v[start]
        for row in range(grid.height):
            if low < row <= high:
                u_row = u[start] + (row - v[start]) / dv * (u[end] - u[start])
                winding[row, int(np.clip(np.ceil(u_row), 0, grid.width))] += 1 if dv > 0 else -1
    return np.cumsum(winding, axis=1)[:, :grid.width] > 0


@st.composite
def loops_on_a_grid(draw):
    """Up to 4 closed loops (any orientation, self-crossings allowed) over a small grid of any width: vertices
    either anywhere or on the half-pixel lattice (edge ends on row centres, pixel centres on edges), some
    beyond the grid's borders."""
    grid = Grid(width=draw(st.integers(1, 70)), height=draw(st.integers(1, 40)), x_left=draw(st.floats(-3, 3)),
                y_top=draw(st.floats(-3, 3)), px=draw(st.sampled_from([0.1, 0.25, 1 / 3])),
                py=draw(st.sampled_from([0.1, 0.2, 0.3])))
    on_lattice = draw(st.booleans())
    loops = []
    for _ in range(draw(st.integers(1, 4))):
        size = draw(st.integers(3, 9))
        u = draw(st.lists(st.integers(-6, 2 * grid.width + 6), min_size=size, max_size=size))
        v = draw(st.lists(st.integers(-6, 2 * grid.height + 6), min_size=size, max_size=size))
        cells = np.column_stack([u, v]).astype(float) / 2.0
        if not on_lattice:
            cells += draw(st.floats(0.0, 1.0)) * np.sin(np.arange(size)[:, None] + [0.0, 1.0])
        loops.append(np.column_stack([grid.x_left + (cells[:, 0] + 0.5) * grid.px,
                                      grid.y_top - (cells[:, 1] + 0.5) * grid.py]))
    offsets = np.concatenate([[0], np.cumsum([len(loop) for loop in loops])])
    return np.concatenate(loops), offsets, grid


@settings(max_examples=300, deadline=None)
@given(loops_on_a_grid())
def test_packed_mask_follows_the_crossing_rule_bit_for_bit(case):
    """The compiled rasteriser equals the crossing rule evaluated pixel by pixel, bit for bit, for nested and
    crossing loops, vertices on row and pixel centres, loops clipped at every border, any row width (the
    padding bits of the last byte stay 0); its count is the number of solid pixels."""
    points, offsets, grid = case
    packed, solid = packed_mask_and_count(points, offsets, grid)
    expected = crossing_rule_mask(points, offsets, grid)
    np.testing.assert_array_equal(packed, np.packbits(expected, axis=1))
    assert solid == int(expected.sum())


@settings(max_examples=300, deadline=None)
@given(loops_on_a_grid())
def test_the_part_rows_hold_every_solid_pixel(case):
    """part_rows bounds the rows that may hold solid pixels: none lies outside it, for loops on row centres,
    clipped at the borders, nested and crossing; and it spans no more than the rows the loops' points span,
    and a row either side."""
    points, offsets, grid = case
    packed = packed_mask(points, offsets, grid)
    first, stop = part_rows(points, grid)
    assert 0 <= first <= stop <= grid.height
    assert not packed[:first].any() and not packed[stop:].any()
    v = (grid.y_top - points[:, 1]) / grid.py - 0.5
    assert stop - first <= v.max() - v.min() + 3


def test_no_loops_make_an_empty_mask():
    """No points: an all-zero packed image of the grid's shape and a count of 0."""
    grid = Grid(width=13, height=5, x_left=0.0, y_top=0.0, px=0.1, py=0.1)
    packed, solid = packed_mask_and_count(np.zeros((0, 2)), np.array([0]), grid)
    assert packed.shape == (5, 2) and not packed.any() and solid == 0
    assert part_rows(np.zeros((0, 2)), grid) == (0, 0)


def test_grid_geometry_and_canvas():
    """Pixel centres sit at x_left + (c + 1/2) px, y_top - (r + 1/2) py; a canvas centres the part."""
    grid = grid_for(np.array([[0.0, 0.0], [10.0, 5.0]]), (254.0, 127.0), margin_mm=1.0)
    assert (grid.px, grid.py) == pytest.approx((0.1, 0.2))
    assert grid.width == 120 and grid.height == 35
    x, y = grid.centres()
    assert x[0] == pytest.approx(grid.x_left + 0.05) and y[0] == pytest.approx(grid.y_top - 0.1)
    assert (x[0] + x[-1]) / 2 == pytest.approx(5.0) and (y[0] + y[-1]) / 2 == pytest.approx(2.5)
    canvas = grid_for(np.array([[0.0, 0.0], [10.0, 5.0]]), (254.0, 254.0), canvas_mm=(20.0, 30.0))
    assert (canvas.width, canvas.height) == (200, 300)
    with pytest.raises(InputError):
        grid_for(np.array([[0.0, 0.0], [10.0, 5.0]]), (254.0, 254.0), canvas_mm=(5.0, 30.0))


def test_rgba_layer_shows_contour_colours_and_base_inside():
    """Contour pixels carry the nearest intersection point's colour; interior pixels the base colour."""
    square = np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])
    colors = np.array([[255.0, 0, 0], [255.0, 0, 0], [0, 0, 255.0], [0, 0, 255.0]])
    grid = Grid(width=50, height=50, x_left=-2.5, y_top=2.5, px=0.1, py=0.1)
    image, solid = render_layer(square, np.array([0, 4]), grid, point_colors=colors, base_color=(10, 20, 30))
    assert image.shape == (50, 50, 4) and solid == 40 * 40
    assert (image[..., 3] > 0).sum() == solid
    assert tuple(image[25, 25, :3]) == (10, 20, 30)  # centre: base
    assert tuple(image[44, 7, :3]) == (255, 0, 0)  # bottom-left corner, near the red points (y = -2)
    assert tuple(image[5, 40, :3]) == (0, 0, 255)  # top-right corner, near the blue points (y = +2)
    assert image[0, 0, 3] == 0
