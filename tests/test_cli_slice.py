"""Tests of cli/slice.py: option parsing, library errors named by the options that set the parameter, and
several models per call (one stack each, patterns expanded, failures reported per model)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from heoslice.cli.slice import flag_error, parse_dpi
from heoslice.errors import EXIT_INPUT, EXIT_OUTPUT, InputError
from heoslice.stack import verify_stack


@pytest.mark.parametrize("text, expected", [("600", (600.0, 600.0)), ("600x300", (600.0, 300.0)),
                                            ("1200X1200", (1200.0, 1200.0))])
def test_parse_dpi_accepts_n_and_nxm(text, expected):
    """--dpi takes N or NxM."""
    assert parse_dpi(text) == expected


@pytest.mark.parametrize("text", ["", "abc", "0", "-5", "600x", "1x2x3"])
def test_parse_dpi_rejects_nonsense(text):
    """Anything else is a one-line input error."""
    with pytest.raises(InputError, match="--dpi"):
        parse_dpi(text)


@pytest.mark.parametrize("message, shown", [
    ("layer_height_mm: must be at least 0.001 mm", "--layer: must be at least 0.001 mm"),
    ("canvas_mm: 5 x 5 mm is smaller than the part", "--canvas: 5 x 5 mm is smaller than the part"),
    ("part.ply: no faces", "part.ply: no faces"),
    ("dpi_like: not a parameter of the slice", "dpi_like: not a parameter of the slice"),
])
def test_library_errors_name_the_option_that_sets_their_parameter(message, shown):
    """An error naming a SliceSpec parameter is shown with its option; any other message is left as it is."""
    assert str(flag_error(InputError(message))) == shown


FAST = ["--dpi", "50", "--layer", "1", "-j", "1"]


def write_box(path: Path, height: float = 10.0) -> Path:
    """A closed 10 x 10 x ``height`` mm box as an ASCII OFF file (outward faces)."""
    corners = [(x, y, z) for z in (0.0, height) for y in (0.0, 10.0) for x in (0.0, 10.0)]
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    triangles = [tri for a, b, c, d in quads for tri in ((a, b, c), (a, c, d))]
    lines = ["OFF", f"{len(corners)} {len(triangles)} 0"]
    lines += [" ".join(f"{v:g}" for v in corner) for corner in corners]
    lines += ["3 " + " ".join(map(str, tri)) for tri in triangles]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def models(tmp_path, monkeypatch) -> Path:
    """A folder of two boxes (10 and 5 mm tall) and a broken file; the working directory is tmp_path."""
    monkeypatch.chdir(tmp_path)
    write_box(tmp_path / "scans" / "tall.off", 10.0)
    write_box(tmp_path / "scans" / "short.off", 5.0)
    (tmp_path / "broken.off").write_text("OFF\n8 12 0\n0 0 0\n")
    return tmp_path


def test_each_model_goes_to_its_own_stack(run_cli, models):
    """`slice a b` writes ./a_stack and ./b_stack, each a verified stack of its own model's layers."""
    code, out, err = run_cli("slice", "scans/tall.off", "scans/short.off", *FAST)
    assert code == 0, err
    assert len(out.splitlines()) == 2
    for name, layers in (("tall", 10), ("short", 5)):
        report = verify_stack(models / f"{name}_stack")
        assert report.ok and len(report.manifest["layers"]) == layers


def test_quoted_pattern_is_expanded_and_json_is_a_list(run_cli, models):
    """A pattern the shell left alone is expanded (sorted) by heoslice; --json is a list, one object per model."""
    code, out, err = run_cli("slice", "scans/*.off", "--into", "stacks", "--json", *FAST)
    assert code == 0, err
    entries = json.loads(out)
    assert [entry["model"] for entry in entries] == ["scans/short.off", "scans/tall.off"]
    assert all(entry["ok"] for entry in entries)
    assert [entry["stack"] for entry in entries] == ["stacks/short_stack", "stacks/tall_stack"]
    assert verify_stack(models / "stacks" / "tall_stack").ok


def test_one_literal_model_gives_one_object(run_cli, models):
    """One model named literally: --json is one object that names the model and says ok."""
    code, out, err = run_cli("slice", "scans/tall.off", "-o", "t", "--json", *FAST)
    assert code == 0, err
    summary = json.loads(out)
    assert summary["model"] == "scans/tall.off" and summary["ok"] is True and summary["layers"] == 10


def test_a_failing_model_does_not_stop_the_others(run_cli, models):
    """Bad input (2) and a non-empty output (3) each give one line, the good model is sliced, exit is the worst."""
    (models / "short_stack").mkdir()
    (models / "short_stack" / "keep.txt").write_text("mine")
    code, out, err = run_cli("slice", "broken.off", "scans/short.off", "scans/tall.off", "--json", *FAST)
    assert code == EXIT_OUTPUT
    lines = err.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith("heoslice: error: ") for line in lines)
    assert "broken.off" in lines[0] and "short_stack" in lines[1]
    assert lines[2] == "heoslice: error: 2 of 3 models failed: broken.off, scans/short.off"
    entries = json.loads(out)
    assert [(entry["ok"], entry.get("exit_code")) for entry in entries] == [
        (False, EXIT_INPUT), (False, EXIT_OUTPUT), (True, None)]
    assert verify_stack(models / "tall_stack").ok
    assert (models / "short_stack" / "keep.txt").read_text() == "mine"


def test_pattern_matching_nothing_is_one_failure(run_cli, models):
    """A pattern that matches no file is reported in its place (exit 2) and the other models still run."""
    code, out, err = run_cli("slice", "scans/tall.off", "nothing/*.stl", "scans/short.off", "--json", *FAST)
    assert code == EXIT_INPUT
    assert "heoslice: error: nothing/*.stl: no file matches this pattern" in err
    assert [entry["model"] for entry in json.loads(out)] == ["scans/tall.off", "nothing/*.stl", "scans/short.off"]
    assert verify_stack(models / "tall_stack").ok and verify_stack(models / "short_stack").ok


@pytest.mark.parametrize("arguments", [("scans/tall.off", "scans/short.off", "-o", "out"),
                                       ("scans/*.off", "-o", "out"),
                                       ("scans/tall.off", "-o", "out", "--into", "elsewhere")])
def test_output_names_one_stack_only(run_cli, models, arguments):
    """-o with several models (or a pattern), or with --into, is refused before anything is written."""
    code, _, err = run_cli("slice", *arguments, *FAST)
    assert code == EXIT_INPUT and err.count("\n") == 1 and "--into" in err
    assert not any(models.glob("*_stack")) and not (models / "out").exists()


def test_two_models_with_one_stack_name_are_refused(run_cli, models):
    """a/x.off and b/x.off would share ./x_stack: refused up front, nothing sliced."""
    write_box(models / "a" / "x.off")
    write_box(models / "b" / "x.off")
    code, _, err = run_cli("slice", "a/x.off", "b/x.off", *FAST)
    assert code == EXIT_INPUT and "would both be sliced into" in err
    assert not (models / "x_stack").exists()


MATERIALS = '[materials.gel]\ncolor = "#f0f0f0"\nchannel = 1\n\n[materials.cells]\ncolor = "0,255,0"\nchannel = 2\n'


def count_reads(monkeypatch, path: Path) -> list[Path]:
    """The reads of ``path`` by the materials loader from now on (each call of its bounded read, listed)."""
    from heoslice.material import materials as module

    reads: list[Path] = []
    real = module.read_bounded

    def counted(target, *args, **kwargs):
        if Path(target).resolve() == path.resolve():
            reads.append(Path(target))
        return real(target, *args, **kwargs)

    monkeypatch.setattr(module, "read_bounded", counted)
    return reads


@pytest.mark.parametrize("extra, arguments", [
    ("", ("scans/tall.off",)),
    ("\n[shells]\n0 = \"cells\"\n", ("scans/tall.off", "--grade", "linear", "--to", "gel")),
    ("\n[parts]\ntall = \"gel\"\nshort = \"cells\"\n", ("scans/tall.off", "scans/short.off")),
], ids=["plain", "graded-with-shells", "parts"])
def test_materials_file_is_read_once_per_slice(run_cli, models, monkeypatch, extra, arguments):
    """One slice reads its --materials file once (its materials, [shells] and [parts] come from that read),
    whether it is plain, graded with per-shell materials, or a multi-part job; the stack is still made."""
    path = models / "mats.toml"
    path.write_text(MATERIALS + extra)
    reads = count_reads(monkeypatch, path)
    code, _, err = run_cli("slice", *arguments, "--materials", path, "-o", "out", *FAST)
    assert code == 0, err
    assert len(reads) == 1
    assert verify_stack(models / "out").ok


@pytest.mark.parametrize("text", ["[materials.gel\ncolor = 1\n", "[shells]\n0 = \"gel\"\n",
                                  MATERIALS + "\n[shells]\n0 = \"nothing-such\"\n"],
                         ids=["not-toml", "no-materials", "bad-shell"])
def test_a_bad_materials_file_is_one_line_naming_it(run_cli, models, text):
    """A materials file that is not TOML, has no materials or names an unknown shell material: one line
    naming --materials and the file, exit 2, nothing written."""
    path = models / "mats.toml"
    path.write_text(text)
    code, out, err = run_cli("slice", "scans/tall.off", "--materials", path, "-o", "out", *FAST)
    assert code == EXIT_INPUT and out == ""
    assert err.count("\n") == 1 and err.startswith(f"heoslice: error: --materials: {path}: ")
    assert not (models / "out").exists()


def _label_map(path: Path) -> Path:
    import nibabel as nib
    import numpy as np

    data = np.zeros((6, 6, 6), np.uint8)
    data[1:5, 1:5, 1:5] = 1
    nib.save(nib.Nifti1Image(data, np.diag([2.0, 2.0, 2.0, 1.0])), str(path))
    return path


@pytest.mark.parametrize("order", ["volumes", "mesh-first"])
def test_two_volumes_or_a_volume_and_a_mesh_is_one_line(run_cli, models, order):
    """Two volumes on one command line (or a volume after a mesh) are one line saying one volume per run, not a
    misleading 'unsupported file type'; nothing is written."""
    first, second = _label_map(models / "a.nii.gz"), _label_map(models / "b.nii.gz")
    inputs = [first, second] if order == "volumes" else ["scans/tall.off", second]
    code, out, err = run_cli("slice", *inputs, *FAST)
    assert code == EXIT_INPUT and out == "" and err.count("\n") == 1
    assert "one volume per run" in err and "unsupported" not in err
    assert not list(models.glob("*_stack"))


@pytest.mark.parametrize("flag", [["--up", "A"], ["--smooth", "1"], ["--labels", "seg.nii.gz"],
                                  ["--as", "labels"]], ids=lambda flag: flag[0] if isinstance(flag, list) else flag)
def test_volume_options_with_a_mesh_are_refused(run_cli, models, flag):
    """A volume-only option given with a mesh is one line naming it, not silently ignored; nothing written."""
    code, out, err = run_cli("slice", "scans/tall.off", *flag, "-o", "out", *FAST)
    assert code == EXIT_INPUT and out == "" and err.count("\n") == 1
    assert f"{flag[0]}: only used when slicing a volume" in err
    assert not (models / "out").exists()
