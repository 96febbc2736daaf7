"""Per-pixel shares halftoned (grading/pixel_mix.py): every solid pixel jets exactly one material, empty pixels
none, a pixel jets the target exactly where its dither threshold is below its f, and over each aligned 16 x 16
tile of one f the target's share is within 1/512 of f."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.grading.halftone import thresholds
from heoslice.grading.pixel_mix import fraction_planes, levels_below
from heoslice.layers.rasterising import Grid


def test_levels_below_counts_the_dither_levels_under_f():
    f = np.array([0.0, 0.5 / 256, 0.5 / 256 + 1e-12, 0.5, 1.0])
    levels = (np.arange(256) + 0.5) / 256
    assert levels_below(f).tolist() == [(levels < v).sum() for v in f]


@pytest.mark.parametrize("layer", [0, 7])
@pytest.mark.parametrize("start, target, channels", [(0, 1, 2), (1, 0, 2), (2, 0, 3)])
def test_each_pixel_jets_the_target_where_its_threshold_is_below_f(layer, start, target, channels):
    rng = np.random.default_rng(layer)
    grid = Grid(96, 64, 0.0, 10.0, 0.1, 0.1)
    solid = np.zeros((grid.height, grid.width), dtype=bool)
    solid[:, 16:96] = True
    solid[5, 40] = False
    packed = np.packbits(solid, axis=1)
    tile_f = rng.random((grid.height // 16, grid.width // 16))
    f = np.kron(tile_f, np.ones((16, 16)))
    own = rng.random(f.shape) < 0.01
    f[own] = rng.random(int(own.sum()))  # some pixels of their own f
    planes = fraction_planes(packed, (0, 64, 16, 96), f[:, 16:], grid, layer, start, target, channels)
    masks = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
    assert (masks.sum(axis=0) == solid).all()
    others = [c for c in range(channels) if c not in (start, target)]
    assert not masks[others].any()
    t = thresholds((grid.height, grid.width), layer)
    assert (masks[target][solid] == (t < f)[solid]).all()
    for i in range(4):
        for j in range(2, 6):
            box = (slice(16 * i, 16 * i + 16), slice(16 * j, 16 * j + 16))
            plain = solid[box] & ~own[box]
            if solid[box].all() and not own[box].any():
                assert abs(masks[target][box].mean() - tile_f[i, j]) <= 1 / 512
            assert (masks[target][box][plain] == (t[box] < tile_f[i, j])[plain]).all()


@pytest.mark.parametrize("method", ["blue-noise", "error-diffusion"])
@pytest.mark.parametrize("share", [0.3, 0.7])
def test_other_halftone_methods_keep_one_material_per_pixel_and_the_share(method, share):
    """With --halftone blue-noise or error-diffusion the field interior's masks still give every solid pixel
    exactly one of its two materials, none to an empty pixel, and deliver the share f within 1 % over a
    constant 256 x 192 box (the halftone of heoslice.grading.halftone.halftone)."""
    from heoslice.grading.diffusion import DiffusionCarry

    grid = Grid(272, 200, 0.0, 10.0, 0.1, 0.1)
    solid = np.zeros((grid.height, grid.width), dtype=bool)
    solid[4:196, 16:272] = True
    planes = fraction_planes(np.packbits(solid, axis=1), (4, 196, 16, 272), np.float32(share), grid, 3, 0, 1, 2,
                             method=method, carry=DiffusionCarry() if method == "error-diffusion" else None)
    masks = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
    assert (masks.sum(axis=0) == solid).all()
    assert abs(masks[1][solid].mean() - share) <= 0.01


@pytest.mark.parametrize("method", ["ordered", "blue-noise"])
@pytest.mark.parametrize("kind", ["point", "axis"])
def test_a_closed_form_fields_masks_follow_f_of_each_pixels_exact_r(kind, method):
    """field_planes of a point- or axis-referenced sine (the field interior's ordered or blue-noise dither, by the
    same compiled pass): each solid pixel
    jets the target exactly where its threshold is below f at its own r (from the closed-form distance written
    out here, rounded to the field's steps; a pixel whose r lies within rounding of a step's edge may take
    either neighbour's f), and over the layer the target's share is the mean of f within 1 %."""
    from heoslice.grading.pixel_mix import field_planes
    from heoslice.material import make_function
    from heoslice.material.design import Design, ReferenceRecord
    from heoslice.material.field import R_STEPS, material_field
    from heoslice.material.materials import Material

    at, unit = (0.4, -0.3, 0.2), (0.0, 0.6, 0.8)
    design = Design(Material("a", (0, 0, 0), 1), Material("b", (255, 255, 255), 2),
                    ReferenceRecord(kind, at, unit if kind == "axis" else None),
                    make_function("sine", periods=3), (0.0, 5.0))
    field = material_field(design)
    grid = Grid(203, 180, -5.0, 4.0, 0.05, 0.05)
    solid = np.random.default_rng(9).random((grid.height, grid.width)) < 0.9
    solid[:11] = False
    solid[:, :13] = False
    z = 0.7
    planes = field_planes(field, np.packbits(solid, axis=1), grid, z, 6, 1, 0, 3, method)
    masks = np.unpackbits(planes, axis=2, count=grid.width).astype(bool)
    assert (masks[:2].sum(axis=0) == solid).all() and not masks[2].any()
    rows, cols = np.nonzero(solid)
    o = np.column_stack([grid.x_left + (cols + 0.5) * grid.px, grid.y_top - (rows + 0.5) * grid.py,
                         np.full(len(rows), z)]) - np.array(at)
    d = np.linalg.norm(o, axis=1) if kind == "point" else np.linalg.norm(np.cross(o, np.array(unit)), axis=1)
    r = np.clip(d / 5.0, 0.0, 1.0)
    t = thresholds((grid.height, grid.width), 6, method=method)[rows, cols]
    f = field.fraction_table
    jets = [t < f[np.clip(np.rint(r * R_STEPS).astype(np.int64) + step, 0, R_STEPS)] for step in (-1, 0, 1)]
    got = masks[0][rows, cols]
    assert ((got == jets[1]) | (got == jets[0]) | (got == jets[2])).all()
    assert (got == jets[1]).mean() > 0.999
    assert abs(got.mean() - np.clip(0.5 * np.sin(6 * np.pi * r) + 0.5, 0, 1).mean()) <= 0.01


def test_a_closed_form_fields_empty_layer_has_empty_masks():
    """field_planes of a layer without solid pixels: every mask empty, of the layer's shape."""
    from heoslice.grading.pixel_mix import field_planes
    from heoslice.material import make_function
    from heoslice.material.design import Design, ReferenceRecord
    from heoslice.material.field import material_field
    from heoslice.material.materials import Material

    design = Design(Material("a", (0, 0, 0), 1), Material("b", (255, 255, 255), 2),
                    ReferenceRecord("point", (0.0, 0.0, 0.0), None), make_function("linear"), (0.0, 5.0))
    grid = Grid(45, 30, -2.0, 2.0, 0.1, 0.1)
    planes = field_planes(material_field(design), np.zeros((30, 6), np.uint8), grid, 0.0, 2, 0, 1, 2)
    assert planes.shape == (2, 30, 6) and not planes.any()
