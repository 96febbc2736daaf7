"""Multi-part jobs: several parts sliced into one stack, each part's pixels carrying its material, overlaps
decided by the documented priority (higher priority, then smaller volume), checked against manifold3d slices."""

from __future__ import annotations

import json

import manifold3d
import numpy as np
import pytest
import shapely
import trimesh

from heoslice.material import Material, PartSetting
from heoslice.mesh import Part
from heoslice.pipeline.parts import compose_part_masks, part_order, plan_parts
from heoslice.stack import read_layer_channels, read_layer_mask

MATERIALS_TOML = """
[materials.tissue]
color = "#c04030"
channel = 1
[materials.tumour]
color = "#30c040"
channel = 2
[materials.blood]
color = "#2040ff"
channel = 3
"""
MATERIAL_OF = {"organ": "tissue", "lesion": "tumour", "vessel": "blood"}


def segmented_organ() -> dict[str, trimesh.Trimesh]:
    """An ellipsoidal organ, a spherical lesion inside it, and a vessel (a cylinder along x) crossing both."""
    organ = trimesh.creation.icosphere(3, 1.0)
    organ.apply_scale([12.0, 9.0, 8.0])
    lesion = trimesh.creation.icosphere(2, 3.0)
    lesion.apply_translation([3.0, 0.5, 0.4])
    vessel = trimesh.creation.cylinder(1.3, 32.0, sections=24)
    vessel.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    vessel.apply_translation([0.0, 0.0, 1.1])
    return {"organ": organ, "lesion": lesion, "vessel": vessel}


def section(mesh: trimesh.Trimesh, z: float):
    """The shapely region of a part's cross-section at height z, from manifold3d's slice."""
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(mesh.vertices, np.float64),
                                                  tri_verts=np.ascontiguousarray(mesh.faces, np.uint64)))
    assert solid.status() == manifold3d.Error.NoError
    rings = [np.asarray(ring) for ring in solid.slice(float(z)).to_polygons() if len(ring) >= 3]
    outer = [shapely.Polygon(r) for r in rings if shapely.LinearRing(r).is_ccw]
    holes = [shapely.Polygon(r) for r in rings if not shapely.LinearRing(r).is_ccw]
    return shapely.difference(shapely.union_all(outer), shapely.union_all(holes))


def reference_masks(parts: dict[str, trimesh.Trimesh], ranked: list[str], manifest: dict, index: int):
    """Per part (its own pixels after the parts ranked before it took theirs), by pixel centres in shapely
    regions, and the union of the part boundaries (to excuse centres lying on one)."""
    image = manifest["image"]
    (x_left, y_top), (px, py) = image["origin_mm"], manifest["pixel_size_mm"]
    x = x_left + (np.arange(image["width"]) + 0.5) * px
    y = y_top - (np.arange(image["height"]) + 0.5) * py
    grid_x, grid_y = np.meshgrid(x, y)
    z = manifest["layers"][index]["z_mm"]
    claimed, own = shapely.Polygon(), {}
    regions = {name: section(parts[name], z) for name in ranked}
    for name in ranked:
        own[name] = shapely.contains_xy(shapely.difference(regions[name], claimed), grid_x, grid_y)
        claimed = shapely.union(claimed, regions[name])
    edges = shapely.union_all([region.boundary for region in regions.values()])
    return own, edges, grid_x, grid_y, regions


def write_parts(tmp_path, parts: dict[str, trimesh.Trimesh], toml_parts: str) -> list:
    paths = []
    for name, mesh in parts.items():
        mesh.export(tmp_path / f"{name}.stl")
        paths.append(tmp_path / f"{name}.stl")
    (tmp_path / "mats.toml").write_text(MATERIALS_TOML + toml_parts)
    return paths


@pytest.mark.parametrize("toml_parts, ranked", [
    ('[parts]\norgan = "tissue"\nlesion = "tumour"\nvessel = "blood"\n', ["lesion", "vessel", "organ"]),
    ('[parts]\norgan = "tissue"\nlesion = "tumour"\nvessel = { material = "blood", priority = 1 }\n',
     ["vessel", "lesion", "organ"]),
])
def test_segmented_organ_matches_manifold_reference(tmp_path, run_cli, toml_parts, ranked):
    """Three files sliced in one job through the command line: every layer's droplet masks are, pixel for pixel,
    each part's manifold3d cross-section minus the parts ranked before it (smaller volume first by default, an
    explicit priority first), except at centres on a boundary; the solid mask is their union."""
    parts = segmented_organ()
    paths = write_parts(tmp_path, parts, toml_parts)
    code, out, err = run_cli("slice", *paths, "--materials", tmp_path / "mats.toml", "-o", tmp_path / "stack",
                             "--layer", "0.8", "--dpi", "127", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert [p["name"] for p in sorted(summary["parts"], key=lambda p: p["rank"])] == ranked
    manifest = json.loads((tmp_path / "stack" / "manifest.json").read_text())
    assert [m["name"] for m in manifest["grading"]["materials"]] == ["tissue", "tumour", "blood"]
    contested = 0
    for index in range(len(manifest["layers"])):
        own, edges, grid_x, grid_y, regions = reference_masks(parts, ranked, manifest, index)
        masks = read_layer_channels(tmp_path / "stack", manifest, index)
        by_material = {channel["material"]: mask for channel, mask in zip(manifest["layers"][index]["channels"],
                                                                              masks)}
        solid = read_layer_mask(tmp_path / "stack", manifest, index)
        union = np.zeros_like(solid)
        for name in ranked:
            wrong = by_material[MATERIAL_OF[name]] != own[name]
            if wrong.any():
                distance = shapely.distance(edges, shapely.points(grid_x[wrong], grid_y[wrong]))
                assert distance.max() < 1e-6, (index, name, int(wrong.sum()))
            union |= own[name]
        assert np.count_nonzero(solid != union) <= np.count_nonzero(
            shapely.distance(edges, shapely.points(grid_x, grid_y)) < 1e-6)
        contested += int(np.count_nonzero(shapely.contains_xy(
            shapely.intersection(regions["lesion"], regions["vessel"]), grid_x, grid_y)))
    assert contested > 50  # the lesion and the vessel overlap: the priority is exercised


def test_part_order_is_priority_then_smaller_volume_then_listed_first():
    """Ranks: a higher priority first; equal priorities (None counts as 0) by smaller volume; equal volumes in
    the order listed."""
    assert part_order([100.0, 5.0, 20.0], [None, None, None]) == (1, 2, 0)
    assert part_order([100.0, 5.0, 20.0], [1, None, None]) == (0, 1, 2)
    assert part_order([100.0, 5.0, 20.0], [None, -1, None]) == (2, 0, 1)
    assert part_order([7.0, 7.0], [None, 0]) == (0, 1)


def test_compose_gives_each_pixel_to_the_first_ranked_part():
    """Random packed part masks composed by priority equal the per-pixel rule computed on unpacked booleans:
    the material of the first part (in rank order) that holds the pixel, nothing where none does."""
    rng = np.random.default_rng(3)
    masks = {label: rng.integers(0, 256, (9, 5), dtype=np.uint8) for label in range(3)}
    table = {"a": Material("a", (0, 0, 0), 1), "b": Material("b", (255, 0, 0), 2)}
    parts = [Part(f"p{i}", tmp, "0" * 64, volume) for i, (tmp, volume) in enumerate(
        [("p0.stl", 30.0), ("p1.stl", 10.0), ("p2.stl", 20.0)])]
    plan = plan_parts(parts, table, {"p0": PartSetting("a"), "p1": PartSetting("b"), "p2": PartSetting("a")})
    solid, planes = compose_part_masks(masks, plan, (9, 5))
    bits = {label: np.unpackbits(mask, axis=1).astype(bool) for label, mask in masks.items()}
    winner = np.where(bits[1], 1, np.where(bits[2], 2, np.where(bits[0], 0, -1)))
    expected_b = winner == 1
    np.testing.assert_array_equal(np.unpackbits(planes[1], axis=1).astype(bool), expected_b)
    np.testing.assert_array_equal(np.unpackbits(planes[0], axis=1).astype(bool), (winner == 0) | (winner == 2))
    np.testing.assert_array_equal(np.unpackbits(solid, axis=1).astype(bool), winner >= 0)


def test_uncoloured_parts_and_colours_map_by_the_documented_rule():
    """A part without a setting takes its 3MF material's name when the table has it, else the material nearest
    its one colour; the droplet masks' materials follow the printer channels."""
    table = {"gel": Material("gel", (240, 240, 240), 2), "cells": Material("cells", (0, 255, 0), 1)}
    parts = [Part("a", "a.ply", "0" * 64, 1.0, color=(10, 200, 30)),
             Part("b", "b.3mf", "0" * 64, 2.0, color=(0, 255, 0), material_name="GEL")]
    plan = plan_parts(parts, table, {})
    assert [m.name for m in plan.materials] == ["cells", "gel"]
    assert plan.part_material == (0, 1)
