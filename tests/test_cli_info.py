"""`heoslice info` (cli/info.py): every shell listed with the number [shells] and --shell-colors use, a flat mesh
described with a warning, and many shells in bounded time and memory (an inexact volume rather than a wait)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.mesh import load_mesh


def tetrahedra(centres: np.ndarray, size: float) -> trimesh.Trimesh:
    """One outward tetrahedron of edge ~``size`` mm at each of ``centres`` (n, 3): n separate shells."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float) * size
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    vertices = (centres[:, None, :] + corners[None]).reshape(-1, 3)
    return trimesh.Trimesh(vertices, (faces[None] + 4 * np.arange(len(centres))[:, None, None]).reshape(-1, 3),
                           process=False)


def test_every_shell_is_listed_with_its_number_triangles_volume_and_box(tmp_path, run_cli):
    """A box holding a smaller box, and a third box apart: three shells numbered 0, 1, 2 in the order
    --shell-colors takes them, each with its triangles, enclosed volume and bounding box; the volume counts the
    nested box once (manifold3d's union) and the apart box by itself."""
    path = tmp_path / "three.ply"
    procedural.concatenate(procedural.box((20, 20, 20)), procedural.box((4, 4, 4), origin=(8, 8, 8)),
                           procedural.box((2, 2, 2), origin=(40, 0, 0))).export(path)
    code, out, err = run_cli("info", path, "--json")
    summary = json.loads(out)
    assert code == 0 and summary["volume_mm3"] == pytest.approx(8008.0) and summary["volume_exact"]
    shells = summary["shell_list"]
    mesh = load_mesh(path)
    assert [s["number"] for s in shells] == [0, 1, 2]
    for shell in shells:
        faces = mesh.faces[mesh.shell == shell["number"]]
        corners = mesh.vertices[faces].reshape(-1, 3)
        assert shell["triangles"] == len(faces)
        assert np.allclose(shell["bounds_mm"], [corners.min(axis=0), corners.max(axis=0)], atol=1e-6)
        assert shell["volume_mm3"] == pytest.approx(trimesh.Trimesh(mesh.vertices, faces).volume)
    code, out, _ = run_cli("info", path)
    assert "  shell 1:" in out and "64 mm^3, x 8 .. 12" in out
    code, _, err = run_cli("color", path, "--shell-colors", "1=255,0,0", "-o", tmp_path / "c.ply")
    coloured = load_mesh(tmp_path / "c.ply")
    inner = coloured.shell == 1
    assert code == 0, err
    assert np.all(coloured.colors[np.unique(coloured.faces[inner])] == [255, 0, 0])


def test_a_flat_mesh_is_described_with_a_warning(tmp_path, run_cli):
    """A mesh of zero height: info exits 0 and warns (slice still refuses it, exit 2)."""
    path = tmp_path / "flat.ply"
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]).export(path)
    code, out, err = run_cli("info", path)
    assert code == 0 and "warning:            the mesh has zero height" in out, out + err
    assert run_cli("slice", path, "-o", tmp_path / "s")[0] == 2


@pytest.fixture(scope="module")
def many_shells(tmp_path_factory):
    """100,000 separate tiny tetrahedra on a grid (400,000 triangles), and 100,000 all overlapping."""
    folder = tmp_path_factory.mktemp("shells")
    grid = np.stack(np.meshgrid(np.arange(50), np.arange(50), np.arange(40), indexing="ij"), -1).reshape(-1, 3)
    tetrahedra(grid * 2.0, 1.0).export(folder / "apart.ply")
    rng = np.random.default_rng(1)
    tetrahedra(rng.random((100_000, 3)) * 0.5, 1.0).export(folder / "piled.ply")
    return folder


@pytest.mark.parametrize("name, exact", [("apart", True), ("piled", False)])
def test_info_of_100000_shells_is_bounded(many_shells, name, exact):
    """`info` of 100,000 shells ends within a minute and a few hundred MB: apart, the volume is the sum of the
    shells' (exact, no union needed); piled on each other, too many to unite in bounded time, it is reported
    not exact instead of waited for."""
    from test_mesh_limits import run_bounded

    code, out, err, seconds, rss = run_bounded("info", many_shells / f"{name}.ply", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["shells"] == 100_000 and len(summary["shell_list"]) == 100_000
    assert summary["volume_exact"] is exact
    if exact:
        assert summary["volume_mm3"] == pytest.approx(100_000 / 6.0)
    assert seconds < 60.0 and rss < 1500.0, (seconds, rss)


@pytest.mark.parametrize("command", ["info", "slice"])
def test_a_stack_folder_given_as_a_model_is_one_line(tmp_path, run_cli, command):
    """A heoslice stack folder given to info or slice (as a model) is named as a stack, with the commands that read
    one, exit 2: not a DICOM error about its first layer file."""
    from heoslice import procedural

    procedural.box((6.0, 6.0, 2.0)).export(tmp_path / "box.ply")
    assert run_cli("slice", tmp_path / "box.ply", "--layer", "1", "--dpi", "50", "-o", tmp_path / "stack")[0] == 0
    code, out, err = run_cli(command, tmp_path / "stack")
    assert code == 2 and err.count("\n") == 1 and "is a heoslice stack" in err and "DICOM" not in err, err
