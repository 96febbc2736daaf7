"""The one volume implementation: `info` and `verify --mesh` report the same solid volume, overlaps counted once."""

from __future__ import annotations

import json

import manifold3d
import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.mesh import load_mesh, solid_volume_mm3


def two_boxes(second_offset: float, second_size: float) -> trimesh.Trimesh:
    """A 20 mm cube at the origin and a second cube (its own shell) of the given size shifted along x."""
    first = trimesh.creation.box(extents=(20.0, 20.0, 20.0))
    second = trimesh.creation.box(extents=(second_size,) * 3)
    second.apply_translation((second_offset, 0.0, 0.0))
    return trimesh.util.concatenate([first, second])


CASES = {  # name: (mesh, independent volume of the union, mm^3)
    "nested": (two_boxes(0.0, 8.0), 20.0 ** 3),  # a lesion-like cube inside the organ-like one
    "overlapping": (two_boxes(15.0, 20.0), 20.0 ** 3 * 2 - 5.0 * 20.0 * 20.0),  # 5 mm overlap along x
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_info_and_verify_agree_on_the_union_volume(tmp_path, run_cli, name):
    """For nested and for overlapping shells, `info --json` and `verify --mesh --json` give the same volume,
    the analytic volume of the union (each shell's volume counted once where they overlap)."""
    mesh, expected = CASES[name]
    path = tmp_path / f"{name}.ply"
    mesh.export(path)
    code, out, err = run_cli("info", path, "--json")
    assert code == 0, err
    info_volume = json.loads(out)["volume_mm3"]
    code, _, err = run_cli("slice", path, "-o", tmp_path / "stack", "--dpi", "100", "--layer", "1")
    assert code == 0, err
    code, out, err = run_cli("verify", tmp_path / "stack", "--mesh", path, "--json", "--tolerance", "1")
    assert code == 0, err + out
    verify_volume = json.loads(out)["mesh"]["volume_mm3"]
    assert info_volume == pytest.approx(expected, rel=1e-9)
    assert verify_volume == info_volume
    assert mesh.volume > expected + 100.0  # the sum of the shells would be wrong: the test can tell


def test_solid_volume_is_manifold3d_union(tmp_path):
    """On shells of random spheres, solid_volume_mm3 is manifold3d's union volume of the shells, not their sum."""
    rng = np.random.default_rng(3)
    spheres = [trimesh.creation.icosphere(2, float(r)).apply_translation(c)
               for r, c in zip(rng.uniform(3, 6, 4), rng.uniform(-4, 4, (4, 3)))]
    path = tmp_path / "spheres.ply"
    trimesh.util.concatenate(spheres).export(path)
    parts = [manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(s.vertices, np.float32),
                                                 tri_verts=np.asarray(s.faces, np.uint32))) for s in spheres]
    union = parts[0]
    for part in parts[1:]:
        union = union + part
    volume, exact = solid_volume_mm3(load_mesh(path))
    assert exact
    assert volume == pytest.approx(union.volume(), rel=1e-5)
    assert volume < 0.95 * sum(s.volume for s in spheres)


def test_ranked_part_volumes_take_overlaps_from_the_lower_ranks(tmp_path):
    """Two 10 mm cubes overlapping by 5 x 10 x 10 mm and a separate 2 mm cube: the part ranked first keeps its
    1000 mm^3, the other cube loses the 500 mm^3 overlap, whichever order; the separate cube keeps 8 mm^3
    (the analytic volumes)."""
    from heoslice.mesh import load_assembly, ranked_part_volumes_mm3

    procedural.box((10.0, 10.0, 10.0)).export(tmp_path / "a.ply")
    procedural.box((10.0, 10.0, 10.0), origin=(5.0, 0.0, 0.0)).export(tmp_path / "b.ply")
    procedural.box((2.0, 2.0, 2.0), origin=(30.0, 0.0, 0.0)).export(tmp_path / "c.ply")
    mesh = load_assembly([tmp_path / name for name in ("a.ply", "b.ply", "c.ply")])
    assert ranked_part_volumes_mm3(mesh, (0, 1, 2)) == pytest.approx([1000.0, 500.0, 8.0])
    assert ranked_part_volumes_mm3(mesh, (1, 2, 0)) == pytest.approx([500.0, 1000.0, 8.0])
