"""Colouring meshes and writing the coloured PLY; the ``heoslice color`` command.

References: exact r and f on procedural meshes (a box about its base plane, a sphere
about its centre), the mesh read back by heoslice.mesh.load_mesh and by trimesh,
and trimesh's own check of watertightness after subdivision.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from heoslice import procedural
from heoslice.errors import InputError, OutputError
from heoslice.material import (
    ColorSpec,
    Material,
    color_mesh,
    default_output,
    make_function,
    ply_bytes,
    subdivide,
    write_ply,
)
from heoslice.mesh import MATERIAL_PROPERTY, Mesh, load_mesh

REPO = Path(__file__).resolve().parents[1]
VASE = REPO / "examples" / "vase.ply"


def save(mesh: trimesh.Trimesh, path: Path) -> Path:
    """Write a procedural mesh as binary PLY and return its path."""
    path.write_bytes(mesh.export(file_type="ply", encoding="binary"))
    return path


@pytest.fixture
def box_mesh(tmp_path):
    """A 20 x 10 x 8 mm box from z = 2 with vertex rings at a few heights, loaded by heoslice."""
    return load_mesh(save(procedural.box((20.0, 10.0, 8.0), origin=(0.0, 0.0, 2.0), z_cuts=(3.0, 5.0, 9.5)),
                          tmp_path / "box.ply"))


def test_box_linear_about_base_plane(box_mesh):
    """Default reference and linear f: material = (z - 2) / 8 and colour = M1 + f (M2 - M1) at every vertex."""
    colored = color_mesh(box_mesh, ColorSpec(make_function("linear")))
    expected = (box_mesh.vertices[:, 2] - 2.0) / 8.0
    assert np.array_equal(colored.r, expected)
    assert np.array_equal(colored.material, expected.astype(np.float32).astype(np.float64))
    m1, m2 = np.array([240, 240, 240]), np.array([0, 255, 0])
    assert np.array_equal(colored.colors, np.rint(m1 + expected[:, None] * (m2 - m1)).astype(np.uint8))
    assert colored.colors.dtype == np.uint8


@pytest.mark.parametrize("kind, expected", [
    ("constant", lambda r: np.ones_like(r)),
    ("quadratic", lambda r: r ** 2),
    ("sine", lambda r: 0.5 + 0.5 * np.sin(2 * np.pi * r)),
])
def test_box_other_functions(box_mesh, kind, expected):
    """Constant, quadratic and sine on the box follow eq. 2, 4, 5 of r = (z - 2) / 8, clipped to [0, 1]."""
    colored = color_mesh(box_mesh, ColorSpec(make_function(kind)))
    r = (box_mesh.vertices[:, 2] - 2.0) / 8.0
    assert np.allclose(colored.material, np.clip(expected(r), 0, 1), rtol=0, atol=1e-7)


def in_memory(mesh: trimesh.Trimesh) -> Mesh:
    """A heoslice Mesh straight from a trimesh, float64 coordinates untouched (no file round trip)."""
    return Mesh(vertices=np.asarray(mesh.vertices, dtype=np.float64), faces=np.asarray(mesh.faces, dtype=np.int64),
                colors=None, material=None, shell=np.zeros(len(mesh.faces), dtype=np.int64),
                source=Path("memory"), sha256="", warnings=())


def test_sphere_about_centre_is_one_colour():
    """A sphere coloured about its centre has a single colour and fraction (r = 1 everywhere)."""
    mesh = in_memory(procedural.sphere(radius=10.0, subdivisions=3))
    colored = color_mesh(mesh, ColorSpec(make_function("quadratic", alpha=0.5), reference="point", at=(0, 0, 0)))
    assert np.allclose(colored.r, 1.0, rtol=0, atol=1e-12)
    assert np.all(colored.material == np.float32(0.5)) and len(np.unique(colored.colors, axis=0)) == 1


def test_range_and_clipping(box_mesh):
    """--range 4 8 mm maps z - 2 = 4 to r = 0 and 8 to r = 1; outside it r (and f) are clipped."""
    colored = color_mesh(box_mesh, ColorSpec(make_function("linear", alpha=2.0, lam=-0.5), r_range=(4.0, 8.0)))
    r = np.clip((box_mesh.vertices[:, 2] - 2.0 - 4.0) / 4.0, 0, 1)
    assert np.array_equal(colored.r, r)
    assert np.allclose(colored.material, np.clip(2 * r - 0.5, 0, 1), rtol=0, atol=1e-12)


@pytest.mark.parametrize("ascii_ply", [False, True])
def test_ply_round_trip(tmp_path, ascii_ply):
    """Written PLY (binary or ASCII) reads back with the same vertices, faces, RGB and float material."""
    mesh = load_mesh(VASE)
    colored = color_mesh(mesh, ColorSpec(make_function("sine", periods=3)))
    path = write_ply(tmp_path / "out.ply", colored, ascii=ascii_ply)
    header = path.read_bytes()[:2000].split(b"end_header")[0].decode()
    assert ("format ascii" in header) == ascii_ply
    assert f"property float {MATERIAL_PROPERTY}" in header and "property uchar red" in header
    back = load_mesh(path)
    assert np.array_equal(back.vertices, colored.vertices)
    assert np.array_equal(back.faces, colored.faces)
    assert np.array_equal(back.colors, colored.colors)
    assert np.array_equal(back.material, colored.material)
    other = trimesh.load(path, process=False)  # an independent reader agrees on the colours
    assert np.array_equal(np.asarray(other.visual.vertex_colors)[:, :3], colored.colors)


def test_double_coordinates_when_float_is_not_exact(tmp_path):
    """Coordinates that float32 cannot hold exactly are written as double, so they read back exactly."""
    mesh = load_mesh(save(procedural.sphere(radius=10.0, subdivisions=1), tmp_path / "s.ply"))
    colored = color_mesh(mesh, ColorSpec(make_function("linear"), max_edge=1.3))
    assert b"property double x" in ply_bytes(colored).split(b"end_header")[0]
    for ascii_ply in (False, True):
        back = load_mesh(write_ply(tmp_path / f"d{ascii_ply}.ply", colored, ascii=ascii_ply))
        assert np.array_equal(back.vertices, colored.vertices)
        assert np.array_equal(back.material, colored.material)


def test_subdivision(tmp_path):
    """--max-edge: no edge longer than asked, still watertight, same volume, reads back vertex for vertex."""
    mesh = load_mesh(VASE)
    colored = color_mesh(mesh, ColorSpec(make_function("linear"), max_edge=2.0))
    edges = np.linalg.norm(colored.vertices[colored.faces] - colored.vertices[np.roll(colored.faces, 1, axis=1)],
                           axis=2)
    assert edges.max() <= 2.0 and len(colored.faces) > 4 * len(mesh.faces)
    before = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    after = trimesh.Trimesh(colored.vertices, colored.faces, process=False)
    assert after.is_watertight and after.volume == pytest.approx(before.volume, rel=1e-9)
    back = load_mesh(write_ply(tmp_path / "fine.ply", colored))
    assert np.array_equal(back.vertices, colored.vertices) and np.array_equal(back.material, colored.material)
    z = colored.vertices[:, 2]
    assert np.allclose(colored.r, (z - z.min()) / np.ptp(z), rtol=0, atol=1e-12)


def test_subdivision_refusals():
    """A non-positive or absurdly small max edge is an InputError, before any memory is spent."""
    vertices = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0]], dtype=float)
    faces = np.array([[0, 1, 2]])
    with pytest.raises(InputError, match="positive"):
        subdivide(vertices, faces, 0.0)
    with pytest.raises(InputError, match="would make about"):
        subdivide(vertices, faces, 1e-4)


def test_shell_materials(tmp_path):
    """A shell given its own material is that colour with fraction 1; the other shell follows the function."""
    mesh = load_mesh(save(procedural.nested_shells(outer=20.0, inner=5.0, subdivisions=2), tmp_path / "n.ply"))
    assert mesh.shell.max() == 1
    tumour = Material("tumour", (200, 0, 0), 3)
    inner_shell = int(mesh.shell[np.argmin(np.linalg.norm(mesh.vertices[mesh.faces[:, 0]] - [4, 0, 0], axis=1))])
    colored = color_mesh(mesh, ColorSpec(make_function("linear"), shell_materials=((inner_shell, tumour),)))
    mine = colored.vertex_shell == inner_shell
    assert mine.any() and (~mine).any()
    assert np.all(colored.colors[mine] == (200, 0, 0)) and np.all(colored.material[mine] == 1.0)
    assert np.allclose(colored.material[~mine], colored.r[~mine], rtol=0, atol=1e-7)
    assert any("shell" in line and "tumour 200,0,0 channel 3" in line for line in colored.comments)
    with pytest.raises(InputError, match="shell 5 does not exist"):
        color_mesh(mesh, ColorSpec(shell_materials=((5, tumour),)))


def test_surface_reference(tmp_path):
    """A second mesh as reference: r is each vertex's distance to it over the largest such distance."""
    organ = procedural.sphere(radius=20.0, subdivisions=3)
    lesion_path = save(procedural.sphere(radius=4.0, subdivisions=2, center=(6.0, 0.0, 0.0)), tmp_path / "l.ply")
    mesh = load_mesh(save(organ, tmp_path / "organ.ply"))
    colored = color_mesh(mesh, ColorSpec(make_function("linear"), reference="surface", surface=lesion_path))
    lesion = trimesh.load(lesion_path, process=False)
    _, d, _ = trimesh.proximity.closest_point(lesion, mesh.vertices)
    assert np.allclose(colored.r, d / d.max(), rtol=0, atol=1e-9)
    with pytest.raises(InputError, match="^surface: .*no such file"):
        color_mesh(mesh, ColorSpec(reference="surface", surface=tmp_path / "absent.ply"))
    with pytest.raises(InputError, match="needs a second mesh"):
        color_mesh(mesh, ColorSpec(reference="surface"))


def test_write_refuses_existing_and_leaves_nothing(tmp_path, box_mesh):
    """An existing output is not overwritten without force; a failed write leaves no file or temporary."""
    colored = color_mesh(box_mesh, ColorSpec())
    target = write_ply(tmp_path / "a.ply", colored)
    with pytest.raises(OutputError, match="exists"):
        write_ply(target, colored)
    write_ply(target, colored, force=True)
    with pytest.raises(OutputError, match="does not exist"):
        write_ply(tmp_path / "nowhere" / "b.ply", colored)
    with pytest.raises(OutputError, match=r"\.ply"):
        write_ply(tmp_path / "b.stl", colored)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ply", "box.ply"]


def test_default_output_name():
    """Without -o the output sits beside the model as <stem>_<function>.ply."""
    assert default_output(Path("/data/vase.ply"), make_function("linear")) == Path("/data/vase_linear.ply")
    assert default_output(Path("liver.stl"), make_function("sine")) == Path("liver_sine.ply")


# --- the command ----------------------------------------------------------------------------

@pytest.fixture
def vase_copy(tmp_path):
    """examples/vase.ply copied into an empty folder."""
    target = tmp_path / "vase.ply"
    target.write_bytes(VASE.read_bytes())
    return target


def test_cli_color_as_documented(run_cli, vase_copy, monkeypatch):
    """`heoslice color vase.ply --func linear` writes vase_linear.ply beside the input, binary, readable back."""
    monkeypatch.chdir(vase_copy.parent)
    code, out, err = run_cli("color", "vase.ply", "--func", "linear")
    assert code == 0, err
    written = vase_copy.parent / "vase_linear.ply"
    assert written.is_file() and "vase_linear.ply" in out
    assert b"format binary_little_endian" in written.read_bytes()[:200]
    back = load_mesh(written)
    z = back.vertices[:, 2]
    assert np.allclose(back.material, (z - z.min()) / np.ptp(z), rtol=0, atol=1e-7)


def test_cli_options(run_cli, vase_copy, tmp_path):
    """-o, --ascii, a materials file with --from/--to names, sine with --periods, point reference with --at."""
    materials = tmp_path / "m.toml"
    materials.write_text('[materials.gel]\ncolor = "white"\nchannel = 1\n[materials.ink]\ncolor = "#ff0000"\n'
                         'channel = 2\n')
    out_path = tmp_path / "red.ply"
    code, _, err = run_cli("color", vase_copy, "-o", out_path, "--func", "sine", "--periods", "2", "--ascii",
                           "--materials", materials, "--from", "gel", "--to", "ink", "--ref", "point",
                           "--at", "0,0,30")
    assert code == 0, err
    assert out_path.read_bytes().startswith(b"ply\nformat ascii 1.0\n")
    back = load_mesh(out_path)
    r = np.linalg.norm(back.vertices - [0, 0, 30], axis=1)
    f = np.clip(0.5 + 0.5 * np.sin(4 * np.pi * r / r.max()), 0, 1)
    assert np.allclose(back.material, f, rtol=0, atol=1e-6)
    assert np.array_equal(back.colors, np.rint([255, 255, 255] + f[:, None] * ([255, 0, 0] - np.array([255, 255, 255])))
                          .astype(np.uint8))


def test_cli_expression_and_surface(run_cli, vase_copy, tmp_path):
    """--expr alone selects the expression function; --ref surface --surface measures to a second mesh."""
    lesion = save(procedural.sphere(radius=3.0, subdivisions=2, center=(0.0, 0.0, 30.0)), tmp_path / "lesion.ply")
    code, _, err = run_cli("color", vase_copy, "--expr", "r**2*(3-2*r)", "--ref", "surface", "--surface", lesion,
                           "-o", tmp_path / "e.ply")
    assert code == 0, err
    back = load_mesh(tmp_path / "e.ply")
    _, d, _ = trimesh.proximity.closest_point(trimesh.load(lesion, process=False), back.vertices)
    r = d / d.max()
    assert np.allclose(back.material, r ** 2 * (3 - 2 * r), rtol=0, atol=1e-6)


@pytest.mark.parametrize("args, option", [
    (["--func", "spline"], "--func"),
    (["--ref", "cone"], "--ref"),
    (["--range", "5", "5"], "--range"),
    (["--range", "5", "2"], "--range"),
    (["--ref", "surface", "--surface", "absent.ply"], "--surface"),
    (["--ref", "surface", "--surface", "garbage.ply"], "--surface"),
    (["--ref", "surface"], "--surface"),
    (["--to", "blurple"], "--to"),
    (["--from", "1,2"], "--from"),
    (["--at", "1,2"], "--at"),
    (["--normal", "0,0,0"], "--normal"),
    (["--ref", "point", "--normal", "0,0,1"], "--normal"),
    (["--expr", "import os"], "--expr"),
    (["--expr", "sqrt(r - 2)"], "--expr"),
    (["--max-edge", "0"], "--max-edge"),
    (["--max-edge", "0.00001"], "--max-edge"),
    (["--max-edge", "1e-308"], "--max-edge"),
    (["--at", "1e308,1e308,1e308"], "--at"),
    (["--ref", "point", "--at", "1e308,0,0"], "--at"),
    (["--ref", "axis", "--at", "0,-1e308,0"], "--at"),
    (["--shell-colors", "7=red"], "--shell-colors"),
    (["--shell-colors", "red"], "--shell-colors"),
    (["--materials", "absent.toml"], "--materials"),
    (["--ref", "point", "--at", "0,0,30", "--range", "0", "0"], "--range"),
])
@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_cli_bad_input(run_cli, vase_copy, monkeypatch, args, option):
    """Bad input: exit 2, one line naming the option, and no output file (nor temporary) left behind; no
    overflow (a RuntimeWarning, made an error here) on the way."""
    monkeypatch.chdir(vase_copy.parent)
    (vase_copy.parent / "garbage.ply").write_bytes(b"ply\nthis is not a mesh\n")
    before = sorted(os.listdir(vase_copy.parent))
    code, out, err = run_cli("color", "vase.ply", *args)
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("heoslice: error: ") and option in lines[0], err
    assert sorted(os.listdir(vase_copy.parent)) == before


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("flag, huge, plain", [("--normal", "1e308,1e308,0", "1,1,0"),
                                               ("--direction", "0,-1e308,1e308", "0,-1,1")])
def test_cli_huge_direction_is_the_same_direction(run_cli, vase_copy, flag, huge, plain):
    """A normal or axis direction of huge components is the direction it points in: the same colours as
    the small one, without overflow."""
    ref = ["--ref", "axis"] if flag == "--direction" else []
    for name, vector in (("huge", huge), ("plain", plain)):
        code, _, err = run_cli("color", vase_copy, *ref, flag, vector, "-o", vase_copy.parent / f"{name}.ply")
        assert code == 0, err
    assert np.array_equal(load_mesh(vase_copy.parent / "huge.ply").material,
                          load_mesh(vase_copy.parent / "plain.ply").material)


def test_cli_existing_output(run_cli, vase_copy):
    """An existing output file is an output error (exit 3) unless --force, which replaces only a PLY heoslice
    color wrote: a file the user made stays as it was."""
    target = vase_copy.parent / "vase_linear.ply"
    target.write_bytes(b"old")
    code, _, err = run_cli("color", vase_copy)
    assert code == 3 and "exists" in err and target.read_bytes() == b"old"
    code, _, err = run_cli("color", vase_copy, "--force")
    assert code == 3 and "not a coloured PLY heoslice wrote" in err and target.read_bytes() == b"old"
    target.unlink()
    assert run_cli("color", vase_copy)[0] == 0
    code, _, err = run_cli("color", vase_copy, "--force")
    assert code == 0 and load_mesh(target).material is not None


def test_cli_help_has_examples(run_cli):
    """--help shows examples, including the documented `heoslice color vase.ply --func linear`."""
    code, out, _ = run_cli("color", "--help")
    assert code == 0 and "heoslice color vase.ply --func linear" in out and "--shell-colors" in out


# --- issue 23: file mode, --json, the written function --------------------------------------

@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_cli_ply_mode_follows_umask(run_cli, vase_copy, umask, mode):
    """`color` writes its PLY with 0666 less the umask (as stacks and PNGs are), not the temporary file's 0600."""
    previous = os.umask(umask)
    try:
        code, _, err = run_cli("color", vase_copy, "-o", vase_copy.parent / "out.ply")
    finally:
        os.umask(previous)
    assert code == 0, err
    assert (vase_copy.parent / "out.ply").stat().st_mode & 0o777 == mode


def test_cli_json_summary(run_cli, vase_copy):
    """`color --json` prints one JSON object: output, counts, the function and reference as written, r and f
    ranges, the materials; nothing else on stdout."""
    import json

    target = vase_copy.parent / "q.ply"
    code, out, err = run_cli("color", vase_copy, "--func", "quadratic", "--alpha", "2", "--lambda", "-0.5",
                             "-o", target, "--json")
    assert code == 0, err
    summary = json.loads(out)
    back = load_mesh(target)
    assert summary["output"] == str(target) and summary["vertices"] == len(back.vertices)
    assert summary["triangles"] == len(back.faces)
    assert summary["function"] == "quadratic: f = 2*r^2 - 0.5"
    assert summary["r"] == [0.0, 1.0] and summary["f"] == [0.0, 1.0]
    assert summary["from"]["name"] == "M1" and summary["to"] == {"name": "M2", "color": [0, 255, 0], "channel": 2}


@pytest.mark.parametrize("args, written", [
    (["--func", "quadratic", "--alpha", "2", "--lambda", "-0.5"], "quadratic: f = 2*r^2 - 0.5"),
    (["--func", "linear", "--alpha", "-1", "--lambda", "1"], "linear: f = -1*r + 1"),
    (["--func", "quadratic", "--beta", "0.5", "--alpha", "0"], "quadratic: f = 0.5*r + 0"),
    (["--func", "linear"], "linear: f = 1*r + 0"),
])
def test_cli_function_written_properly(run_cli, vase_copy, args, written):
    """The function in the summary and the PLY comment leaves out zero terms and subtracts negative ones
    (no '+ 0*r + -0.5'); the constant term is always shown."""
    target = vase_copy.parent / "w.ply"
    code, out, err = run_cli("color", vase_copy, *args, "-o", target)
    assert code == 0, err
    assert written in out
    assert f"comment heoslice color: {written}\n".encode() in target.read_bytes()[:1000]


def test_fig2_without_its_environment_fails_in_one_line(tmp_path):
    """examples/fig2.py run by a Python without heoslice (here: without site-packages) exits non-zero with one
    line that says to run it with the project's Python, and writes nothing."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-S", str(REPO / "examples" / "fig2.py"), str(tmp_path / "f.png")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=60)
    lines = done.stderr.strip().splitlines()
    assert done.returncode != 0 and len(lines) == 1, done.stderr
    assert lines[0].startswith("fig2.py: error: cannot import") and ".venv/bin/python examples/fig2.py" in lines[0]
    assert not (tmp_path / "f.png").exists()


def test_a_material_named_in_any_script_survives_the_ply(tmp_path):
    """The PLY header is ASCII: a material named 'tümour core' (or in any script) is written (backslash-escaped in
    the readable comment) and read back by name from the recorded design, exactly."""
    from heoslice.material.design import design_of

    start, target = Material("tümour core", (200, 0, 0), 1), Material("肝臓", (240, 240, 240), 2)
    colored = color_mesh(load_mesh(VASE), ColorSpec(m1=start, m2=target))
    path = tmp_path / "v.ply"
    write_ply(path, colored)
    assert path.read_bytes().split(b"end_header")[0].isascii()
    design = design_of(load_mesh(path))
    assert (design.start.name, design.target.name) == (start.name, target.name)
