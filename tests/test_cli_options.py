"""The options shared by ``color`` and ``slice`` (cli/options.py) and the map from library parameters to flags."""

from __future__ import annotations

import click
import pytest

from heoslice.cli.color import color
from heoslice.cli.options import flags
from heoslice.cli.slice import slice_cmd
from heoslice.errors import InputError

SHARED = ("alpha", "beta", "lam", "periods", "expression")


def _options(command: click.Command) -> dict[str, click.Option]:
    return {p.name: p for p in command.params if isinstance(p, click.Option)}


def test_shared_options_are_declared_once():
    """--alpha/--beta/--lambda/--periods/--expr have the same flags and help texts in color and slice."""
    ours, theirs = _options(color), _options(slice_cmd)
    for name in SHARED:
        assert ours[name].opts == theirs[name].opts and ours[name].help == theirs[name].help, name


def test_coefficient_help_shows_the_defaults(run_cli):
    """slice --help shows each coefficient's default per function kind (from the table of kinds)."""
    code, out, _ = run_cli("slice", "--help")
    text = " ".join(out.split())
    assert code == 0
    assert "alpha of eq. 3-5 [default: linear 1, quadratic 1, sine 0.5]" in text
    assert "lambda of eq. 2-5 [default: constant 1, linear 0, quadratic 0, sine 0.5]" in text
    assert "beta of eq. 4-5 [default: quadratic 0, sine 2 pi periods]" in text


def test_flags_rewrite_only_known_parameters():
    """A library error 'alpha: ...' becomes '--alpha: ...'; an unknown prefix is left as it is."""
    with pytest.raises(InputError, match=r"^--lambda: must be finite$"):
        with flags({"lam": "--lambda"}):
            raise InputError("lam: must be finite")
    with pytest.raises(InputError, match=r"^other: problem$"):
        with flags({"lam": "--lambda"}):
            raise InputError("other: problem")


@pytest.mark.parametrize("command", ["color", "slice"])
@pytest.mark.parametrize("args, flag", [
    (["--alpha", "nan"], "--alpha: must be finite"),
    (["--lambda", "inf"], "--lambda: must be finite"),
    (["--beta", "2"], "--beta: beta is not used by the linear function"),
    (["--periods", "2"], "--periods: only applies to the 'sine' function"),
])
def test_function_errors_name_the_flag(run_cli, tmp_path, command, args, flag):
    """A bad coefficient is one line naming its own option, in both commands, exit 2."""
    from heoslice import procedural

    model = tmp_path / "ball.ply"
    model.write_bytes(procedural.sphere(radius=5.0, subdivisions=1).export(file_type="ply"))
    kind = ["--func", "linear"] if command == "color" else ["--grade", "linear"]
    code, _, err = run_cli(command, model, *kind, *args, "-o", tmp_path / ("o.ply" if command == "color" else "s"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and f"heoslice: error: {flag}" in err, err


@pytest.mark.parametrize("args, named", [
    (["--to", "0,255,0"], "--to"),
    (["--from", "M1"], "--from"),
    (["--to", "M2", "--from", "M1", "--alpha", "2"], "--alpha, --to, --from"),
])
def test_slice_refuses_materials_it_would_ignore(run_cli, tmp_path, args, named):
    """`slice vase.ply --to 0,255,0` (or --from) without --grade exits 2 with one line naming the options,
    and leaves no stack (issue 18: they were accepted and ignored)."""
    from pathlib import Path

    vase = Path(__file__).resolve().parents[1] / "examples" / "vase.ply"
    code, out, err = run_cli("slice", vase, *args, "-o", tmp_path / "stack")
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"heoslice: error: {named}: only used with --grade"), err
    assert not (tmp_path / "stack").exists()


def test_a_parts_job_refuses_grading_options_it_would_ignore(run_cli, tmp_path):
    """A multi-part job (--parts) has no --grade: --to and --alpha given to one are refused with one line
    naming them, exit 2, no stack."""
    from pathlib import Path

    vase = Path(__file__).resolve().parents[1] / "examples" / "vase.ply"
    code, out, err = run_cli("slice", vase, vase, "--parts", "--to", "0,255,0", "--alpha", "2",
                             "-o", tmp_path / "stack")
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("heoslice: error: --alpha, --to: only used with --grade"), err
    assert not (tmp_path / "stack").exists()


def test_scale_is_one_option_of_slice_color_and_info():
    """--scale has the same flags, type, default and help in slice, color and info (one declaration)."""
    from heoslice.cli.info import info

    declared = [_options(command)["scale"] for command in (slice_cmd, color, info)]
    assert all((o.opts, o.default, o.help, o.type) == (declared[0].opts, 1.0, declared[0].help, declared[0].type)
               for o in declared)


def test_info_and_color_apply_the_scale(tmp_path, run_cli):
    """info --scale 1000 of a 0.02 x 0.01 x 0.005 m box reports 20 x 10 x 5 mm and 1000 mm^3; color --scale 1000
    writes the PLY in mm (bounds x1000) and measures --range in mm of the scaled model, with --surface scaled
    too; a scale out of range names --scale."""
    import json

    import numpy as np

    from heoslice import procedural
    from heoslice.mesh import load_mesh

    procedural.box((0.02, 0.01, 0.005)).export(tmp_path / "box_m.ply")
    code, out, err = run_cli("info", tmp_path / "box_m.ply", "--scale", "1000", "--json")
    summary = json.loads(out)
    assert code == 0, err
    assert np.allclose(np.subtract(*summary["bounds_mm"][::-1]), [20, 10, 5]) and summary["volume_mm3"] == \
        pytest.approx(1000.0)
    procedural.box((0.002, 0.002, 0.002), origin=(0.0, 0.0, 0.0)).export(tmp_path / "corner_m.ply")
    code, out, err = run_cli("color", tmp_path / "box_m.ply", "--scale", "1000", "--ref", "surface", "--surface",
                             tmp_path / "corner_m.ply", "--range", "0", "10", "-o", tmp_path / "box_mm.ply",
                             "--json")
    assert code == 0, err
    colored = load_mesh(tmp_path / "box_mm.ply")
    assert np.allclose(colored.bounds, [[0, 0, 0], [20, 10, 5]])
    # the box corner (0, 10, 0) lies 8 mm from the 2 mm corner cube: r = 0.8 (unscaled cube: 10 mm, r = 1)
    corner = np.flatnonzero(np.all(np.isclose(colored.vertices, [0.0, 10.0, 0.0]), axis=1))
    assert len(corner) == 1 and colored.material[corner[0]] == pytest.approx(0.8, abs=1e-6)
    code, _, err = run_cli("info", tmp_path / "box_m.ply", "--scale", "1e9")
    assert code == 2 and err.startswith("heoslice: error: --scale: ") and err.count("\n") == 1
