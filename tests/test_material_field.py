"""The design's field in 3D (material/field.py): every voxel's r from its own 3-D distance to the reference, with
the normalisation color used, within 1e-3 of an independent computation; and a slice's delivered share per band
of r follows f(r)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.layers.rasterising import Grid
from heoslice.material import ColorSpec, color_mesh, make_function, write_ply
from heoslice.material.design import Design
from heoslice.material.field import R_TOLERANCE, material_field
from heoslice.mesh import load_mesh
from heoslice.stack.read import read_layer_channels, read_layer_mask

from helpers import lesion_distance

RADIUS = 10.0


def colored_file(mesh: trimesh.Trimesh, folder: Path, name: str, spec: ColorSpec) -> Path:
    source = folder / f"{name}_plain.ply"
    mesh.export(source)
    target = folder / f"{name}.ply"
    write_ply(target, color_mesh(load_mesh(source), spec))
    return target


@pytest.fixture(scope="module")
def sphere(tmp_path_factory) -> tuple[Path, Design]:
    """A sphere about the origin coloured by a point-referenced sine of 3 periods."""
    folder = tmp_path_factory.mktemp("sphere")
    path = colored_file(procedural.sphere(radius=RADIUS, subdivisions=4), folder, "ball",
                        ColorSpec(make_function("sine", periods=3), reference="point", at=(0.0, 0.0, 0.0)))
    return path, Design.from_header(load_mesh(path).comments)


def grid_over(low: float, high: float, px: float) -> Grid:
    width = int(np.ceil((high - low) / px))
    return Grid(width, width, low, high, px, px)


def test_design_records_the_normalisation_color_used(sphere):
    """The recorded range is 0 .. the largest vertex distance, so r at a vertex from the design is its r."""
    path, design = sphere
    mesh = load_mesh(path)
    distance = np.linalg.norm(mesh.vertices, axis=1)
    assert design.r_range == (0.0, float(distance.max()))
    field = material_field(design, path)
    assert np.allclose(field.fraction(field.r_at(mesh.vertices)), mesh.material, atol=1e-6)


def test_sphere_voxel_r_is_the_analytic_r(sphere):
    """Every pixel centre of layers across the sphere: r = |p| / R_max (the analytic distance to the point),
    within 1e-3 (exactly, to rounding)."""
    path, design = sphere
    field = material_field(design, path)
    grid = grid_over(-RADIUS, RADIUS, 0.05)
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(grid.height), np.arange(grid.width), indexing="ij"))
    x = grid.x_left + (cols + 0.5) * grid.px
    y = grid.y_top - (rows + 0.5) * grid.py
    for z in (-9.5, -3.1, 0.05, 4.7, 9.9):
        inside = x ** 2 + y ** 2 + z ** 2 <= RADIUS ** 2
        r = field.layer_r(rows[inside], cols[inside], grid, z)
        truth = np.sqrt(x[inside] ** 2 + y[inside] ** 2 + z ** 2) / design.r_range[1]
        assert np.abs(r - np.clip(truth, 0, 1)).max() < 1e-9


@pytest.fixture(scope="module")
def organ(tmp_path_factory):
    """A liver phantom coloured by distance to its inner lesion (range 0 .. 4 mm)."""
    folder = tmp_path_factory.mktemp("organ")
    organ, lesion = procedural.liver_phantom(scale=0.15, subdivisions=3)
    lesion.export(folder / "lesion.ply")
    path = colored_file(organ, folder, "organ", ColorSpec(make_function("linear"), reference="surface",
                                                          surface=folder / "lesion.ply", r_range=(0.0, 4.0)))
    return path, Design.from_header(load_mesh(path).comments), lesion


def test_lesion_voxel_r_is_the_brute_force_r(organ):
    """Sampled pixel centres of layers through and around the lesion: the lattice-and-refine r is within 1e-3 of
    the brute-force point-to-triangle distance's r, including where whole cells are settled by the bound."""
    path, design, lesion = organ
    field = material_field(design, path)
    centre = lesion.vertices.mean(axis=0)
    grid = Grid(400, 400, centre[0] - 10.0, centre[1] + 10.0, 0.05, 0.05)
    rng = np.random.default_rng(44)
    beyond = 0
    for z in (centre[2] - 3.3, centre[2], centre[2] + 1.7, centre[2] + 6.0):
        rows, cols = rng.integers(0, 400, 3000), rng.integers(0, 400, 3000)
        r = field.layer_r(rows, cols, grid, z)
        x = grid.x_left + (cols + 0.5) * grid.px
        y = grid.y_top - (rows + 0.5) * grid.py
        truth = np.clip(lesion_distance(lesion, np.column_stack([x, y, np.full(len(x), z)])) / 4.0, 0.0, 1.0)
        assert np.abs(r - truth).max() <= R_TOLERANCE / 2 + 1e-12
        beyond += int((truth == 1.0).sum())
    assert beyond > 0


def test_a_changed_reference_surface_is_refused(organ, tmp_path):
    """The design names its reference surface by content: a different file at that path is an error."""
    path, design, lesion = organ
    moved = tmp_path / "lesion.ply"
    lesion.apply_translation((0.5, 0, 0)).export(moved)
    from dataclasses import replace

    from heoslice.errors import InputError
    with pytest.raises(InputError, match="changed"):
        material_field(replace(design, reference=replace(design.reference, surface=str(moved))), path)
    lesion.apply_translation((-0.5, 0, 0))


def test_sphere_delivers_f_per_band_of_r(sphere, run_cli, tmp_path):
    """Sliced in the field interior, the sphere's target share over each band of r (0.05 wide) is the mean of
    f(r) over the band's voxels within 2 %: the sine's shells reach the interior."""
    path, design = sphere
    stack = tmp_path / "stack"
    code, _, err = run_cli("slice", path, "--layer", "0.5", "--dpi", "200", "-o", stack)
    assert code == 0, err
    manifest = json.loads((stack / "manifest.json").read_text())
    assert manifest["grading"]["interior"] == "field"
    names = [c["material"] for c in manifest["layers"][0]["channels"]]
    image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
    x = image["origin_mm"][0] + (np.arange(image["width"]) + 0.5) * px
    y = image["origin_mm"][1] - (np.arange(image["height"]) + 0.5) * py
    bands = np.zeros((20, 3))  # per band: voxels, designed f sum, target voxels
    for index, entry in enumerate(manifest["layers"]):
        solid = read_layer_mask(stack, manifest, index)
        target = read_layer_channels(stack, manifest, index)[names.index(design.target.name)]
        rows, cols = np.nonzero(solid)
        r = np.sqrt(x[cols] ** 2 + y[rows] ** 2 + entry["z_mm"] ** 2) / design.r_range[1]
        f = np.clip(0.5 * np.sin(6 * np.pi * r) + 0.5, 0, 1)
        band = np.minimum((r * 20).astype(int), 19)
        np.add.at(bands, band, np.column_stack([np.ones(len(r)), f, target[rows, cols]]))
    full = bands[:, 0] > 2000
    assert full.sum() >= 15
    error = np.abs(bands[full, 2] / bands[full, 0] - bands[full, 1] / bands[full, 0])
    assert error.max() <= 0.02, error
    # the shells are in the interior: the inner bands' designed f is not the surface's, and is delivered
    assert np.ptp(bands[full, 1] / bands[full, 0]) > 0.5


@pytest.mark.parametrize("kind, at, direction", [("plane", (0.0, 1.0, -2.0), (0.3, -0.2, 0.9)),
                                                 ("point", (1.0, -2.0, 0.5), None),
                                                 ("axis", (0.5, 0.5, 0.0), (1.0, 2.0, 0.5))])
def test_layer_fraction_over_the_grid_is_f_of_each_pixels_r(kind, at, direction):
    """The closed-form grid evaluation of a layer gives, at every solid pixel, f of the analytic r of that
    pixel centre (point, plane and axis distances written out here), to f's single precision (the halftone
    resolves 1/256)."""
    from heoslice.material.design import ReferenceRecord
    from heoslice.material.materials import Material

    unit = None if direction is None else tuple(np.array(direction) / np.linalg.norm(direction))
    design = Design(Material("a", (0, 0, 0), 1), Material("b", (255, 255, 255), 2),
                    ReferenceRecord(kind, at, unit), make_function("sine", periods=2), (0.5, 7.0))
    field = material_field(design)
    grid = Grid(120, 100, -6.0, 5.0, 0.1, 0.1)
    solid = np.zeros((100, 120), dtype=bool)
    solid[13:77, 21:99] = np.random.default_rng(1).random((64, 78)) < 0.8
    packed = np.packbits(solid, axis=1)
    z = 1.3
    (r0, r1, c0, c1), f = field.layer_fraction(packed, grid, z)
    f = np.broadcast_to(f, (r1 - r0, c1 - c0))
    rows, cols = np.nonzero(solid)
    q = np.column_stack([grid.x_left + (cols + 0.5) * 0.1, grid.y_top - (rows + 0.5) * 0.1, np.full(len(rows), z)])
    o = q - np.array(at)
    if kind == "plane":
        d = np.abs(o @ np.array(unit))
    elif kind == "point":
        d = np.linalg.norm(o, axis=1)
    else:
        d = np.linalg.norm(np.cross(o, np.array(unit)), axis=1)
    r = np.clip((d - 0.5) / 6.5, 0, 1)
    assert np.abs(f[rows - r0, cols - c0] - np.clip(0.5 * np.sin(4 * np.pi * r) + 0.5, 0, 1)).max() < 2e-6


@pytest.mark.parametrize("kind, high, cut", [("point", 6.0, 0), ("plane", 6.0, 0), ("axis", 6.0, 0),
                                              ("point", 6.03, 19), ("axis", 6.03, 19)])
def test_layer_square_of_a_closed_form_reference_gives_the_exact_r(kind, high, cut, tmp_path):
    """A layer's squared distance in its frame gives each solid pixel's r to rounding of the closed-form
    distance's r, for a tilted plane and axis too; also where the solid starts ``cut`` columns in (a box not at
    column 0) on a grid whose width is not whole bytes. A closed form has no per-pixel steps (layer_steps)."""
    from dataclasses import replace

    from heoslice.material.field import MaterialField
    from heoslice.material.references import Reference

    geometry = {"point": Reference("point", (0.3, -0.2, 0.1)),
                "plane": Reference("plane", (0.3, -0.2, 0.1), tuple(np.array([1.0, 2.0, 2.0]) / 3.0)),
                "axis": Reference("axis", (0.3, -0.2, 0.1), tuple(np.array([2.0, -1.0, 2.0]) / 3.0))}[kind]
    design = Design.from_header(load_mesh(colored_file(procedural.sphere(radius=1.0, subdivisions=1), tmp_path,
                                                       "b", ColorSpec(make_function("linear")))).comments)
    field = MaterialField(replace(design, r_range=(0.5, 9.0)), geometry)
    grid = grid_over(-6.0, high, 0.1)
    solid = np.random.default_rng(5).random((grid.height, grid.width)) < 0.6
    solid[:, :cut] = False
    packed = np.packbits(solid, axis=1)
    square = field.layer_square(packed, grid, 1.7)
    r0, r1, c0, c1 = square.box
    assert c0 == cut // 8 * 8 and c1 == grid.width and grid.width % 8 == (1 if cut else 0)
    rows, cols = np.nonzero(solid[r0:r1, c0:c1])
    a, b, c, d, e, f = square.square
    u = square.frame[0] + cols * square.frame[1]
    v = square.frame[2] + rows * square.frame[3]
    low, high = square.r_range
    r = np.clip((np.sqrt(np.maximum(a * u * u + b * u * v + c * v * v + d * u + e * v + f, 0.0)) - low)
                / (high - low), 0.0, 1.0)
    x = grid.x_left + (cols + c0 + 0.5) * grid.px
    y = grid.y_top - (rows + r0 + 0.5) * grid.py
    truth = field.r_at(np.column_stack([x, y, np.full(len(x), 1.7)]))
    assert np.abs(r - truth).max() <= 1e-9
    with pytest.raises(ValueError, match="layer_square"):
        field.layer_steps(packed, grid, 1.7)


def test_layer_steps_of_a_surface_are_within_the_tolerance(organ):
    """The lesion's steps: each solid pixel's r within 1e-3 of the brute-force r (the issue's bound: the bounds'
    R_TOLERANCE / 2 and the rounding to r's steps, 1 / (2 R_STEPS), together)."""
    from heoslice.material.field import R_STEPS

    path, design, lesion = organ
    field = material_field(design, path)
    centre = lesion.vertices.mean(axis=0)
    grid = Grid(240, 240, centre[0] - 6.0, centre[1] + 6.0, 0.05, 0.05)
    solid = np.random.default_rng(6).random((240, 240)) < 0.05
    (r0, r1, c0, c1), codes = field.layer_steps(np.packbits(solid, axis=1), grid, centre[2] + 0.8)
    rows, cols = np.nonzero(solid[r0:r1, c0:c1])
    x = grid.x_left + (cols + c0 + 0.5) * grid.px
    y = grid.y_top - (rows + r0 + 0.5) * grid.py
    truth = np.clip(lesion_distance(lesion, np.column_stack([x, y, np.full(len(x), centre[2] + 0.8)])) / 4.0, 0, 1)
    assert np.abs(codes[rows, cols] / R_STEPS - truth).max() <= 1e-3 + 1e-12
