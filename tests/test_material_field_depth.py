"""Grading measured in 3D (`slice --grade ... --depth D --depth-from surface`, material/field.depth_field): the
start-material skin of a graded sphere, and of the shared liver scan on a vertical section, is as thick at the
top and bottom as at the sides (within one nozzle width), against the exact 3-D distance; measured per layer
(the paper's) the top and bottom are not."""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.stack.read import read_layer_channels, read_layer_mask

RADIUS, DEPTH, NOZZLE = 6.0, 2.0, 0.2
#: The liver scan scaled to about 38 x 29 x 26 mm, and its vertical section through the right lobe (a quarter of
#: the width from its left), where the organ has a top, a bottom and sides with enough pixels each at 200 dpi.
LIVER_SCALE, LIVER_SECTION = 6.0, 0.25
BINS = 40

#: (n, 3) voxel centres, mm -> their exact 3-D depth (n,) mm and the unit direction (n, 3) to the nearest surface.
DepthOf = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def sphere_depth(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth below a sphere of RADIUS about the origin, analytically: R - |p|, toward p / |p|."""
    length = np.linalg.norm(points, axis=1)
    return RADIUS - length, points / length[:, None]


def mesh_depth(mesh: trimesh.Trimesh) -> DepthOf:
    """Depth below a closed mesh by trimesh's exact closest point (an implementation independent of heoslice's
    surface search), toward that point."""
    def depth(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        closest, distance, _ = trimesh.proximity.closest_point(mesh, points)
        return distance, (closest - points) / np.maximum(distance, 1e-12)[:, None]
    return depth


def skins(stack, depth_of: DepthOf, section: float | None = None) -> dict[str, float]:
    """The start-material skin's thickness (mm) at the top, bottom and side: the least exact 3-D depth (0.1 mm
    bins) from which the target's delivered share is at least 0.45, over the voxels whose nearest surface point
    lies within 25 degrees of straight up, of straight down, and of horizontal. ``section``: only the voxels of
    the vertical section through the image column at that fraction of its width."""
    manifest = json.loads((stack / "manifest.json").read_text())
    names = [c["material"] for c in manifest["layers"][0]["channels"]]
    image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
    x = image["origin_mm"][0] + (np.arange(image["width"]) + 0.5) * px
    y = image["origin_mm"][1] - (np.arange(image["height"]) + 0.5) * py
    column = None if section is None else int(section * image["width"])
    bins = {name: np.zeros((BINS, 2)) for name in ("top", "bottom", "side")}
    for index, entry in enumerate(manifest["layers"]):
        solid = read_layer_mask(stack, manifest, index)
        target = read_layer_channels(stack, manifest, index)[names.index("M2")]
        if column is not None:
            solid = solid.copy()
            solid[:, :column] = solid[:, column + 1:] = False
        rows, cols = np.nonzero(solid)
        if not len(rows):
            continue
        depth, toward = depth_of(np.column_stack([x[cols], y[rows], np.full(len(rows), entry["z_mm"])]))
        polar = np.degrees(np.arccos(np.clip(toward[:, 2], -1, 1)))
        at = np.minimum((depth / 0.1).astype(int), BINS - 1)
        for name, where in (("top", polar < 25), ("bottom", polar > 155), ("side", np.abs(polar - 90) < 25)):
            np.add.at(bins[name], at[where], np.column_stack([np.ones(where.sum()), target[rows, cols][where]]))
    out = {}
    for name, counts in bins.items():
        share = counts[:, 1] / np.maximum(counts[:, 0], 1)
        reached = (share >= 0.45) & (counts[:, 0] > 50)
        assert reached.any(), (name, counts)
        out[name] = 0.1 * int(np.argmax(reached))
    return out


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ball")
    procedural.sphere(radius=RADIUS, subdivisions=4).export(folder / "ball.ply")
    return folder / "ball.ply"


def graded(run_cli, model, stack, *extra) -> None:
    """Slice ``model`` graded linearly over DEPTH mm at 0.1 mm and 200 dpi into ``stack``."""
    code, _, err = run_cli("slice", model, "--grade", "linear", "--depth", DEPTH, "--nozzle", NOZZLE,
                           "--layer", "0.1", "--dpi", "200", "-o", stack, *extra)
    assert code == 0, err


def test_surface_depth_grades_every_skin_alike(run_cli, ball, tmp_path):
    stack = tmp_path / "surface"
    graded(run_cli, ball, stack, "--depth-from", "surface")
    assert json.loads((stack / "manifest.json").read_text())["grading"]["depth_from"] == "surface"
    skin = skins(stack, sphere_depth)
    assert max(skin.values()) - min(skin.values()) <= NOZZLE + 1e-9, skin
    # linear over 10 sub-regions of 0.2 mm: f >= 0.5 from the fifth, deeper than 0.8 mm
    assert all(abs(value - 0.8) <= NOZZLE + 1e-9 for value in skin.values()), skin


def test_layer_depth_grades_top_and_bottom_otherwise(run_cli, ball, tmp_path):
    """The paper's per-layer measurement (the default) leaves the top and bottom skins thinner than the side's:
    the comparison above is not one every grading passes."""
    stack = tmp_path / "layer"
    graded(run_cli, ball, stack)
    skin = skins(stack, sphere_depth)
    assert skin["side"] - min(skin["top"], skin["bottom"]) > NOZZLE, skin


@pytest.fixture(scope="module")
def liver(shared_data, tmp_path_factory):
    """The shared liver scan, scaled by LIVER_SCALE about the origin (so its depth below the surface is exact
    in the stack's millimetres): (the scaled PLY, the scaled mesh)."""
    mesh = trimesh.load(shared_data / "anatomy" / "sofa_liver_smooth.ply", force="mesh", process=False)
    mesh.apply_scale(LIVER_SCALE)
    path = tmp_path_factory.mktemp("liver") / "liver.ply"
    mesh.export(path)
    return path, mesh


def test_liver_scan_surface_depth_grades_every_skin_alike(run_cli, liver, tmp_path):
    """On a vertical section of the liver scan graded with --depth-from surface, the skin at the top, bottom and
    sides is equally thick within one nozzle width, and about eq. 8's 0.8 mm, by trimesh's exact distance."""
    path, mesh = liver
    stack = tmp_path / "surface"
    graded(run_cli, path, stack, "--depth-from", "surface")
    skin = skins(stack, mesh_depth(mesh), section=LIVER_SECTION)
    assert max(skin.values()) - min(skin.values()) <= NOZZLE + 1e-9, skin
    assert all(abs(value - 0.8) <= NOZZLE + 1e-9 for value in skin.values()), skin


def test_liver_scan_layer_depth_grades_top_and_bottom_otherwise(run_cli, liver, tmp_path):
    """The same section of the liver graded per layer (the paper's) fails the comparison above."""
    path, mesh = liver
    stack = tmp_path / "layer"
    graded(run_cli, path, stack)
    skin = skins(stack, mesh_depth(mesh), section=LIVER_SECTION)
    assert max(skin.values()) - min(skin.values()) > NOZZLE, skin


def test_surface_depth_needs_a_depth(run_cli, ball, tmp_path):
    code, _, err = run_cli("slice", ball, "--grade", "linear", "--depth-from", "surface", "-o", tmp_path / "s")
    assert code == 2 and "--depth-from" in err and "--depth" in err
