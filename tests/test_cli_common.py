"""Shared CLI helpers: message formatting, the JSON convention, expanding patterns; controller --json."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from heoslice.cli.common import (
    echo_json,
    exit_status_epilog,
    expand_inputs,
    plural,
    run_each,
    signed_percent,
)
from heoslice.errors import EXIT_CODES, EXIT_INTERRUPTED, HeosliceError


@pytest.mark.parametrize(("count", "text"), [(0, "0 layers"), (1, "1 layer"), (2, "2 layers")])
def test_plural(count, text):
    """One of a noun is singular, every other count plural."""
    assert plural(count, "layer") == text


@pytest.mark.parametrize(("fraction", "text"), [(-0.00001, "0.00 %"), (0.0, "0.00 %"), (-0.0, "0.00 %"),
                                                (0.0123, "+1.23 %"), (-0.004, "-0.40 %")])
def test_signed_percent_never_shows_minus_zero(fraction, text):
    """A difference that rounds to zero is '0.00 %' (never '-0.00 %'); others keep their sign."""
    assert signed_percent(fraction) == text


def test_exit_status_epilog_reads_the_meanings_from_the_table():
    """The help paragraph lists the given statuses in order, each with its errors.EXIT_CODES meaning."""
    text = exit_status_epilog((130, 0, 2))
    assert text.splitlines()[1:] == ["Exit status:", f"  0    {EXIT_CODES[0]}", f"  2    {EXIT_CODES[2]}",
                                     f"  130  {EXIT_CODES[130]}"]


def test_echo_json_is_strict_single_line_json(capsys):
    """NaN and infinities become null, numpy scalars numbers, paths strings, tuples lists; one line."""
    echo_json({"a": float("nan"), "b": np.float32(1.5), "c": np.int64(3), "d": Path("x/y"), "e": (1, np.inf),
               "f": np.bool_(True)})
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    assert json.loads(out, parse_constant=lambda name: pytest.fail(f"non-standard {name}")) == {
        "a": None, "b": 1.5, "c": 3, "d": "x/y", "e": [1, None], "f": True}


def test_expand_inputs(tmp_path, monkeypatch):
    """Patterns expand sorted and recursively, files are kept once in order, a file named like a pattern is
    taken literally, and a single literal argument is not 'several'."""
    monkeypatch.chdir(tmp_path)
    for name in ("b.ply", "a.ply", "deep/c.ply", "x[1].ply"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text("")
    found = expand_inputs([Path("*.ply"), Path("none/*.stl"), Path("b.ply"), Path("**/c.ply")])
    assert found.items == (Path("a.ply"), Path("b.ply"), Path("x[1].ply"), "none/*.stl", Path("deep/c.ply"))
    assert found.paths == (Path("a.ply"), Path("b.ply"), Path("x[1].ply"), Path("deep/c.ply")) and found.several
    single = expand_inputs([Path("x[1].ply")])
    assert single.paths == (Path("x[1].ply"),) and not single.several
    assert expand_inputs([Path("x*.ply")]).several


def test_controller_json_prints_its_port_as_one_object(run_cli):
    """`controller --pty --json` prints one JSON object naming the pseudo-terminal, and nothing else on stdout."""
    code, out, err = run_cli("controller", "--pty", "--duration", "0.2", "--json")
    assert code == 0, err
    lines = out.splitlines()
    assert len(lines) == 1
    summary = json.loads(lines[0])
    assert summary["ok"] is True and summary["port"].startswith("/dev/")
    assert "0 layers executed" in err


def test_json_convention_holds_for_every_command_with_json(run_cli, tmp_path, monkeypatch):
    """info, slice, verify, print --dry-run, color, preview, export: one line of strict JSON on stdout, an object with ok and its input."""
    from test_cli_slice import write_box

    monkeypatch.chdir(tmp_path)
    write_box(tmp_path / "box.off")
    calls = {"slice": (("slice", "box.off", "--dpi", "254", "--layer", "2", "-j", "1"), "model"),
             "info": (("info", "box.off"), "model"),
             "verify": (("verify", "box_stack", "--mesh", "box.off"), "stack"),
             "print": (("print", "box_stack", "--dry-run"), "stack"),
             "color": (("color", "box.off", "--func", "linear"), "model"),
             "preview": (("preview", "box_stack", "-o", "layer.png"), "stack"),
             "export": (("export", "box_stack", "--format", "png", "-o", "box_png"), "stack")}
    for name, (arguments, key) in calls.items():
        code, out, err = run_cli(*arguments, "--json")
        assert code == 0, (name, err)
        assert out.count("\n") == 1, name
        value = json.loads(out, parse_constant=lambda constant: pytest.fail(f"{name}: {constant}"))
        assert value["ok"] is True and isinstance(value[key], str), name


def test_an_interrupted_input_stops_the_others(tmp_path):
    """An error with the interrupted status (a print's Ctrl-C) is not one input's failure: nothing after it runs."""
    ran = []

    def run(path: Path) -> dict:
        ran.append(path)
        raise HeosliceError("stopped", exit_code=EXIT_INTERRUPTED)

    with pytest.raises(HeosliceError) as caught:
        run_each(expand_inputs([Path("a.ply"), Path("b.ply")]), run, key="model", as_json=False)
    assert caught.value.exit_code == EXIT_INTERRUPTED and ran == [Path("a.ply")]


def test_json_fields_have_one_form_across_commands(run_cli, tmp_path, monkeypatch):
    """The fields several commands print agree: `slice`'s default stack is named as `verify` and `print` name it
    (relative, as a user types it, not absolute), the print log beside it likewise, and `boot_id` is 8 hex digits
    in `print --json` as in `controller --json` and the print log."""
    import re

    from heoslice import procedural

    monkeypatch.chdir(tmp_path)
    procedural.sphere(4.0, subdivisions=2).export(tmp_path / "ball.ply")
    code, out, err = run_cli("slice", "ball.ply", "--layer", "1", "--dpi", "50", "--json")
    assert code == 0, err
    sliced = json.loads(out)["stack"]
    code, out, err = run_cli("verify", "ball_stack", "--json")
    assert code == 0, err
    assert sliced == json.loads(out)["stack"] == "ball_stack"
    code, out, err = run_cli("print", "ball_stack", "--port", "sim://", "--json")
    assert code == 0, err
    printed = json.loads(out)
    assert printed["stack"] == sliced and printed["log"] == "ball_stack.print-log.jsonl"
    assert re.fullmatch(r"[0-9a-f]{8}", printed["boot_id"])
    logged = [json.loads(line) for line in Path(printed["log"]).read_text().splitlines()]
    assert {event["boot_id"] for event in logged if "boot_id" in event} == {printed["boot_id"]}
    code, out, err = run_cli("controller", "--pty", "--duration", "0.1", "--json")
    assert code == 0 and re.fullmatch(r"[0-9a-f]{8}", json.loads(out)["boot_id"])
# --- progress bars, under a real pseudo-terminal -------------------------------------------------------------

def on_terminal(*args: str, timeout: float = 300.0, size: tuple[int, int] = (40, 120)) -> tuple[int, str]:
    """Run ``python -m heoslice ARGS`` with stdout and stderr on a new pseudo-terminal of ``size`` (rows, columns)
    characters (as in a lab's shell, the CI variable unset); return (exit status, everything it wrote there)."""
    import fcntl
    import pty
    import select
    import struct
    import termios
    import subprocess
    import sys
    import time

    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", *size, 0, 0))
    env = {key: value for key, value in os.environ.items() if key != "CI"}
    env["TERM"] = "xterm"
    process = subprocess.Popen([sys.executable, "-m", "heoslice", *map(str, args)], stdin=subprocess.DEVNULL,
                               stdout=follower, stderr=follower, env=env, close_fds=True)
    os.close(follower)
    chunks, deadline = [], time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([leader], [], [], 1.0)
            if ready:
                try:
                    data = os.read(leader, 65536)
                except OSError:  # EIO: every writer has closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif process.poll() is not None:
                break
    finally:
        os.close(leader)
    return process.wait(timeout=60), b"".join(chunks).decode("utf-8", "replace")


def bar_counts(output: str, description: str) -> list[int]:
    """The distinct layer counts a progress bar named ``description`` showed, in the order drawn, and checks
    that each drawing had a rate and a time left."""
    import re

    drawn = re.findall(rf"{re.escape(description)}:[^\r\n]*?(\d+)/(\d+) \[[^\]<]*<([^,\]]*), ([^\]]*)\]", output)
    counts = []
    for done, _total, left, rate in drawn:
        assert left and ("/s" in rate or "s/" in rate), (left, rate)
        if not counts or counts[-1] != int(done):
            counts.append(int(done))
    return counts


@pytest.fixture(scope="module")
def ball_200(tmp_path_factory):
    """A graded ball mesh (20 mm tall: 200 layers of 0.1 mm) and where its stack goes."""
    from heoslice import procedural

    folder = tmp_path_factory.mktemp("progress")
    procedural.sphere(10.0, subdivisions=3).export(folder / "ball.ply")
    return folder


def test_every_long_command_draws_a_moving_bar_on_a_terminal(ball_200):
    """On a pseudo-terminal, slice (two workers: the bar moves per layer written, reported over the workers'
    pipes), verify, preview --section and --sheet, export (png, voxel-print), print --dry-run and a print to
    the simulator each draw a
    bar that advances at least ten times over a 200-layer stack, with a rate and a time left."""
    stack = ball_200 / "stack"
    code, output = on_terminal("slice", ball_200 / "ball.ply", "--layer", "0.1", "--dpi", "150", "--grade", "linear",
                               "--to", "0,255,0", "--channels", "-j", "2", "-o", stack)
    assert code == 0, output
    assert len(json.loads((stack / "manifest.json").read_text())["layers"]) == 200
    assert len(bar_counts(output, "slicing")) >= 10, output[-2000:]
    runs = [
        (("verify", stack), "verifying"),
        (("preview", stack, "--section", "x=0", "-o", ball_200 / "section.png"), "drawing"),
        (("preview", stack, "--sheet", "--layers", "0:200:10", "--tile", "32", "-o", ball_200 / "sheet.png"),
         "drawing"),
        (("export", stack, "--format", "png", "-o", ball_200 / "png"), "exporting png"),
        (("export", stack, "--format", "voxel-print", "--pitch", "0.1", "-o", ball_200 / "voxels"),
         "exporting voxel-print"),
        (("print", stack, "--dry-run"), "verifying"),  # its sample is encoded in the verification's pass
        (("print", stack, "--port", "sim://"), "printing"),
    ]
    for args, description in runs:
        code, output = on_terminal(*args)
        assert code == 0, output
        assert len(bar_counts(output, description)) >= 10, (args, output[-2000:])


def test_a_terminal_of_no_size_still_shows_the_bar(ball_200):
    """A pseudo-terminal that reports 0 x 0 characters (as `script` gives a piped shell): verify still draws a
    bar that advances at least ten times over a 200-layer stack (80 columns assumed; tqdm hid it below a screen of
    0 rows)."""
    stack = ball_200 / "stack0"
    code, output = on_terminal("slice", ball_200 / "ball.ply", "--layer", "0.1", "--dpi", "50", "-o", stack)
    assert code == 0, output
    code, output = on_terminal("verify", stack, size=(0, 0))
    assert code == 0, output
    assert len(bar_counts(output, "verifying")) >= 10, output[-2000:]


def test_no_progress_without_a_terminal_or_with_json(ball_200, tmp_path):
    """With stderr a pipe (and with --json) the same commands write nothing to stderr."""
    from helpers import heoslice

    stack = ball_200 / "quiet"
    done = heoslice("slice", ball_200 / "ball.ply", "--layer", "0.1", "--dpi", "150", "--grade", "linear",
                    "--to", "0,255,0", "--channels", "-j", "2", "-o", stack)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    for args in (("verify", stack), ("preview", stack, "--section", "x=0", "-o", tmp_path / "s.png"),
                 ("export", stack, "--format", "png", "-o", tmp_path / "png"), ("print", stack, "--dry-run")):
        done = heoslice(*args)
        assert done.returncode == 0 and done.stderr == "", (args, done.stderr)
    code, output = on_terminal("verify", stack, "--json")
    assert code == 0 and "verifying" not in output and output.strip().startswith("{"), output
