"""Tests of stack/printable.py: the one rule of which stacks can print, as verify, print (and --dry-run),
export --format voxel-print and slice (a warning) apply it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from printing_jobs import disc_masks, make_stack

from heoslice import procedural
from heoslice.errors import EXIT_INPUT, EXIT_VERIFY, InputError
from heoslice.stack import PRINT_RULES, check_printable, print_refusal, read_manifest


def loose_triangles(count: int = 40, seed: int = 3) -> trimesh.Trimesh:
    """A triangle soup: ``count`` small triangles, none sharing a vertex (encloses no volume)."""
    rng = np.random.default_rng(seed)
    corners = rng.uniform(0.0, 10.0, (count, 1, 3)) + rng.uniform(-0.5, 0.5, (count, 3, 3))
    return trimesh.Trimesh(corners.reshape(-1, 3), np.arange(3 * count).reshape(-1, 3), process=False)


@pytest.fixture(scope="module")
def stacks(tmp_path_factory):
    """A ball sliced as droplet masks, as an RGBA preview, and a triangle soup (every layer empty)."""
    folder = tmp_path_factory.mktemp("printable")
    procedural.sphere(4.0, subdivisions=3).export(folder / "ball.ply")
    loose_triangles().export(folder / "soup.ply")
    from helpers import in_process

    for name, extra in (("masks", ["--channels"]), ("rgba", ["--rgba"])):
        assert in_process("slice", folder / "ball.ply", "--layer", "1", "--dpi", "100", "--grade", "linear",
                          "--to", "0,255,0", "-j", "1", "-o", folder / name, *extra) == 0
    return folder


def test_each_rule_refuses_only_its_stacks():
    """A stack with one solid pixel in mode '1' prints; mode RGBA is refused as preview-only whatever its pixels;
    all layers at 0 solid pixels (or no layers) as empty; the first rule that applies is the refusal."""
    def manifest(mode, solids):
        return {"image": {"mode": mode}, "layers": [{"solid_pixels": n} for n in solids]}

    assert print_refusal(manifest("1", [0, 1, 0])) is None
    assert print_refusal(manifest("L", [5])) is None
    assert print_refusal(manifest("RGBA", [5])).name == "preview-only"
    assert print_refusal(manifest("RGBA", [0])).name == "preview-only"
    assert print_refusal(manifest("1", [0, 0])).name == "empty"
    assert print_refusal(manifest("1", [])).name == "empty"
    assert [rule.name for rule in PRINT_RULES] == ["preview-only", "empty"]
    with pytest.raises(InputError, match=r"^here: cannot print: every layer is empty .*; check the model"):
        check_printable(manifest("1", [0]), "here")


def test_print_refuses_an_rgba_stack_with_one_line(stacks, run_cli):
    """`print --dry-run` and `print --port sim://` of an RGBA stack: exit 2, one line naming the stack and
    saying to slice without --rgba; nothing on stdout. The masks stack of the same ball dry-runs."""
    for extra in (["--dry-run"], ["--port", "sim://"]):
        code, out, err = run_cli("print", stacks / "rgba", *extra)
        assert code == EXIT_INPUT and out == "", (out, err)
        assert err.count("\n") == 1 and err.startswith(f"heoslice: error: {stacks / 'rgba'}: cannot print: ")
        assert "slice the model again without --rgba" in err
    code, out, err = run_cli("print", stacks / "masks", "--dry-run")
    assert code == 0, err


def test_an_all_empty_stack_warns_at_slice_and_is_refused_by_verify_and_print(stacks, run_cli, tmp_path):
    """A triangle soup slices to 0 mm^3: slice exits 0 but warns (text and --json), verify (with and without
    --mesh) fails with the refusal line (exit 4), print --dry-run refuses it (exit 2, one line)."""
    code, out, err = run_cli("slice", stacks / "soup.ply", "--layer", "1", "--dpi", "100", "-j", "1",
                             "-o", tmp_path / "soup")
    assert code == 0, err
    assert f"warning: {tmp_path / 'soup'}: cannot print: every layer is empty" in err
    code, out, _ = run_cli("slice", stacks / "soup.ply", "--layer", "1", "--dpi", "100", "-j", "1",
                           "-o", tmp_path / "soup_json", "--json")
    assert code == 0 and any("cannot print: every layer is empty" in w for w in json.loads(out)["warnings"])
    for extra in ([], ["--mesh", stacks / "soup.ply"]):
        code, out, err = run_cli("verify", tmp_path / "soup", *extra)
        assert code == EXIT_VERIFY and f"{tmp_path / 'soup'}: cannot print: every layer is empty" in out
    code, out, err = run_cli("print", tmp_path / "soup", "--dry-run")
    assert code == EXIT_INPUT and err.count("\n") == 1 and "cannot print: every layer is empty" in err


def test_a_hand_made_empty_stack_is_refused_by_print(tmp_path, run_cli):
    """A stack written by another tool (mode L) whose every mask is empty: print --dry-run refuses it, while
    the same stack with one solid disc dry-runs."""
    empty = make_stack(tmp_path / "empty", [np.zeros((30, 40), dtype=bool)] * 3)
    code, _, err = run_cli("print", empty, "--dry-run")
    assert code == EXIT_INPUT and "every layer is empty" in err
    code, _, err = run_cli("print", make_stack(tmp_path / "disc", disc_masks(3)), "--dry-run")
    assert code == 0, err


def test_verify_and_export_apply_the_same_rule(stacks, run_cli, tmp_path):
    """verify fails an RGBA stack with print's refusal line; export --format voxel-print refuses it with the
    same line (exit 2), writing nothing."""
    code, out, err = run_cli("verify", stacks / "rgba")
    line = f"{stacks / 'rgba'}: cannot print: {PRINT_RULES[0].problem}; {PRINT_RULES[0].remedy}"
    assert code == EXIT_VERIFY and line in out.splitlines()
    code, out, err = run_cli("export", stacks / "rgba", "--format", "voxel-print", "-o", tmp_path / "v")
    assert code == EXIT_INPUT and err == f"heoslice: error: {line}\n" and not (tmp_path / "v").exists()
    code, out, err = run_cli("verify", stacks / "masks", "--json")
    assert code == 0 and json.loads(out)["ok"]
    assert read_manifest(stacks / "rgba")["image"]["mode"] == "RGBA"


def test_the_shared_triangle_soup_cannot_print(shared_data, run_cli, tmp_path):
    """The issue's case: bad/soup.ply (loose triangles) slices to 0 mm^3 with a warning; verify --mesh fails it
    and print --dry-run refuses it, each naming the stack."""
    soup = shared_data / "bad" / "soup.ply"
    code, _, err = run_cli("slice", soup, "--layer", "0.1", "--dpi", "300", "-j", "1", "-o", tmp_path / "soup")
    assert code == 0 and "cannot print: every layer is empty" in err
    code, out, _ = run_cli("verify", tmp_path / "soup", "--mesh", soup)
    assert code == EXIT_VERIFY and f"{tmp_path / 'soup'}: cannot print: every layer is empty" in out
    code, _, err = run_cli("print", tmp_path / "soup", "--dry-run")
    assert code == EXIT_INPUT and err.count("\n") == 1 and str(tmp_path / "soup") in err
