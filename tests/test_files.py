"""The one output rule (heoslice.files.check_output), through every command that writes: slice -o, color -o,
export -o, preview -o and print --log. Each refusal is one line with exit 3, and the stack, its folder, the
input mesh, a test-made FIFO or device node and a symlink's target are byte-identical afterwards; --force
replaces only what heoslice itself wrote.
"""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from heoslice import procedural
from heoslice.errors import EXIT_OUTPUT
from heoslice.files import check_output, partial_path, remove_stale_partials
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.stack import verify_stack


def snapshot(path: Path) -> dict:
    """Every entry under ``path`` (itself included): kind, and the sha256 of regular files and link targets."""
    path = Path(path)
    entries = [path, *sorted(path.rglob("*"))] if path.is_dir() and not path.is_symlink() else [path]
    out = {}
    for entry in entries:
        status = os.lstat(entry)
        if stat.S_ISREG(status.st_mode):
            out[str(entry)] = ("file", hashlib.sha256(entry.read_bytes()).hexdigest())
        elif stat.S_ISLNK(status.st_mode):
            out[str(entry)] = ("link", os.readlink(entry))
        else:
            out[str(entry)] = (stat.S_IFMT(status.st_mode), status.st_rdev)
    return out


def assert_refused(result, *needles: str) -> None:
    """Exit 3 and one line 'heoslice: error: ...' holding every needle."""
    code, _, err = result
    assert code == EXIT_OUTPUT, err
    assert err.count("\n") == 1 and err.startswith("heoslice: error: "), err
    assert all(needle in err for needle in needles), err


@pytest.fixture
def project(tmp_path):
    """A folder holding a mesh and the stack sliced from it (``box.ply``, ``stack/``)."""
    model = tmp_path / "box.ply"
    procedural.box((6.0, 6.0, 2.0)).export(model)
    slice_to_stack(load_mesh(model), tmp_path / "stack", SliceSpec(layer_height_mm=0.5, dpi=(100.0, 100.0)))
    return tmp_path


@pytest.fixture
def specials(tmp_path):
    """A FIFO and, as root, a character device node (a copy of /dev/null's numbers), both made by the test."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    made = [fifo]
    if os.geteuid() == 0:
        node = tmp_path / "null-node"
        os.mknod(node, 0o666 | stat.S_IFCHR, os.stat("/dev/null").st_rdev)
        made.append(node)
    return made


def outputs(project: Path) -> dict:
    """Command line of each writing command with its output option last: OUTPUT is substituted."""
    stack, model = project / "stack", project / "box.ply"
    return {
        "slice": ["slice", model, "--dpi", "100", "--layer", "0.5", "-j", "1", "-o"],
        "color": ["color", model, "-o"],
        "export": ["export", stack, "--format", "png", "-o"],
        "preview": ["preview", stack, "-o"],
        "print": ["print", stack, "--port", "sim://", "--log"],
    }


COMMANDS = ("slice", "color", "export", "preview", "print")


@pytest.mark.parametrize("command", COMMANDS)
def test_a_symlink_as_output_is_refused_and_its_target_untouched(project, run_cli, command):
    """-o / --log naming a symbolic link: one line, exit 3, the link and what it points to unchanged."""
    target = project / "precious.txt"
    target.write_text("the lab's notes\n")
    link = project / ("out.ply" if command == "color" else "out.png" if command == "preview" else "out")
    link.symlink_to(target)
    before = {**snapshot(project / "stack"), **snapshot(target), **snapshot(link)}
    for force in ((), ("--force",)) if command != "print" else ((),):
        assert_refused(run_cli(*outputs(project)[command], link, *force), "symbolic link")
    assert {**snapshot(project / "stack"), **snapshot(target), **snapshot(link)} == before


@pytest.mark.parametrize("command", COMMANDS)
def test_special_files_are_never_replaced(project, specials, run_cli, command):
    """A FIFO or device node as output, with --force too: one line, exit 3, the node still there, same kind."""
    for node in specials:
        before = snapshot(node)
        force = () if command == "print" else ("--force",)
        assert_refused(run_cli(*outputs(project)[command], node, *force), "heoslice never replaces it")
        assert snapshot(node) == before


@pytest.mark.parametrize("command", ("export", "preview", "print"))
def test_the_stack_and_places_in_it_are_never_outputs(project, run_cli, command):
    """-o the stack itself, or a name inside it, with --force: refused, the stack byte-identical and verifying."""
    stack = project / "stack"
    before = snapshot(project)
    force = () if command == "print" else ("--force",)
    for target in (stack, stack / "inside.png"):
        assert_refused(run_cli(*outputs(project)[command], target, *force), "input")
    assert snapshot(project) == before
    assert verify_stack(stack).ok


@pytest.mark.parametrize("command", ("slice", "export"))
def test_a_folder_holding_the_input_is_never_replaced(project, run_cli, command):
    """-o the folder that holds the input (the mesh, the stack) with --force: refused, nothing changed."""
    before = snapshot(project)
    assert_refused(run_cli(*outputs(project)[command], project, "--force"), "holds the input")
    assert snapshot(project) == before


def test_color_never_writes_over_its_input(project, run_cli):
    """color MODEL -o MODEL --force: refused, the model byte-identical."""
    model = project / "box.ply"
    before = snapshot(model)
    assert_refused(run_cli("color", model, "-o", model, "--force"), "is the input")
    assert snapshot(model) == before


@pytest.mark.parametrize("command, name", [("slice", "other"), ("color", "other.ply"), ("export", "other"),
                                           ("preview", "other.png"), ("print", "other.jsonl")])
def test_force_replaces_only_what_heoslice_wrote(project, run_cli, command, name):
    """An existing file or folder the user made is refused even with --force (print appends only to its own
    log); after heoslice wrote the output itself, --force (or a second print) replaces / appends to it."""
    user_made = project / name
    if command in ("slice", "export"):
        user_made.mkdir()
        (user_made / "notes.txt").write_text("mine\n")
    else:
        user_made.write_bytes(b"\x89PNG\r\n\x1a\nnot a heoslice preview" if command == "preview" else b"mine\n")
    before = snapshot(user_made)
    force = () if command == "print" else ("--force",)
    assert_refused(run_cli(*outputs(project)[command], user_made, *force), "not a")
    assert snapshot(user_made) == before
    fresh = project / f"fresh_{name}"
    code, _, err = run_cli(*outputs(project)[command], fresh)
    assert code == 0, err
    if command != "print":
        assert_refused(run_cli(*outputs(project)[command], fresh), "--force")
    again = ("--restart",) if command == "print" else force  # the simulator in this process finished the job
    code, _, err = run_cli(*outputs(project)[command], fresh, *again)
    assert code == 0, err
    assert not [p for p in project.iterdir() if p.name.endswith(".partial")]


def test_export_zip_is_marked_and_replaced_only_with_force(project, run_cli):
    """A zip export carries heoslice's mark, so --force replaces it; a user's zip is never replaced."""
    import zipfile

    stack, mine = project / "stack", project / "mine.zip"
    with zipfile.ZipFile(mine, "w") as archive:
        archive.writestr("a.txt", "mine")
    before = snapshot(mine)
    assert_refused(run_cli("export", stack, "--format", "png", "-o", mine, "--force"), "not an export")
    assert snapshot(mine) == before
    ours = project / "ours.zip"
    assert run_cli("export", stack, "--format", "png", "-o", ours)[0] == 0
    assert run_cli("export", stack, "--format", "png", "-o", ours, "--force")[0] == 0


def test_sigkilled_export_leaves_a_partial_the_next_run_removes(project):
    """A SIGKILLed export leaves at most a hidden '.NAME.PID.*.partial' beside the output; the next export to
    the same output removes it, and no other file of the folder."""
    stack, target = project / "stack", project / "killed"
    process = subprocess.Popen([sys.executable, "-m", "heoslice", "export", str(stack), "--format", "png", "-o",
                                str(target)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not [p for p in project.iterdir() if p.name.endswith(".partial")]:
        time.sleep(0.005)
    process.kill()
    process.wait()
    left = [p for p in project.iterdir() if p.name.endswith(".partial")]
    if not left:  # the export finished first on a fast machine: leave a partial as a killed run would
        left = [Path(str(partial_path(target, folder=True)).replace(f".{os.getpid()}.", f".{process.pid}."))]
        left[0].mkdir()
    assert all(p.name.startswith(".killed.") for p in left) and not target.exists()
    others = snapshot(stack)
    assert subprocess.run([sys.executable, "-m", "heoslice", "export", str(stack), "--format", "png", "-o",
                           str(target)], capture_output=True).returncode == 0
    assert not [p for p in project.iterdir() if p.name.endswith(".partial")]
    assert snapshot(stack) == others


def test_a_living_writers_partial_is_left_alone(tmp_path):
    """remove_stale_partials removes only partials of dead processes, of this very target."""
    mine = partial_path(tmp_path / "out", folder=True)
    other_target = tmp_path / ".other.1.abc.partial"
    other_target.mkdir()
    assert remove_stale_partials(tmp_path / "out") == [] and mine.is_dir() and other_target.is_dir()


def test_check_output_in_the_library(tmp_path):
    """A missing target is free; an empty folder only when the caller says so."""
    assert check_output(tmp_path / "new", "thing", force=False, made_here=lambda p: False) is False
    (tmp_path / "empty").mkdir()
    assert check_output(tmp_path / "empty", "thing", force=False, made_here=lambda p: False, folder=True,
                        empty_folder_is_free=True) is False


def test_print_log_on_a_full_disk_is_one_line_exit_3(project, tmp_path):
    """`print --log` whose file cannot grow (a file size limit, as a full disk refuses the write): one line naming
    the log, exit 3, no traceback; the stack and the log's earlier records unchanged."""
    import resource
    import signal

    log = tmp_path / "full.jsonl"
    log.write_text('{"time": "2026-01-01T00:00:00.000+00:00", "event": "start"}\n')
    size = log.stat().st_size

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    before = {**snapshot(project / "stack"), **snapshot(log)}
    done = subprocess.run([sys.executable, "-m", "heoslice", "print", str(project / "stack"), "--port", "sim://",
                           "--log", str(log)], capture_output=True, text=True, preexec_fn=limit, timeout=120)
    assert done.returncode == EXIT_OUTPUT and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith(f"heoslice: error: {log}: cannot write (file size limit exceeded)"), done.stderr
    assert {**snapshot(project / "stack"), **snapshot(log)} == before


def test_print_log_to_dev_full_is_refused(project, run_cli):
    """`print --log /dev/full` (a device): one line, exit 3, the device untouched."""
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    assert_refused(run_cli("print", project / "stack", "--port", "sim://", "--log", "/dev/full"),
                   "character device")


def test_print_log_that_is_another_file_is_refused_without_offering_force(project, run_cli, tmp_path):
    """`print --log` naming a file that is not a print log: one line, exit 3, the file untouched, and the line
    does not offer --force (print has none: it appends to its own logs and replaces nothing)."""
    other = tmp_path / "notes.txt"
    other.write_text("a lab's notes\n")
    result = run_cli("print", project / "stack", "--port", "sim://", "--log", other)
    assert_refused(result, "is not a print log", "--log")
    assert "--force" not in result[2] and other.read_text() == "a lab's notes\n"


def test_a_signal_between_the_renames_puts_the_old_output_back(tmp_path, monkeypatch):
    """move_into_place interrupted after the old folder output was moved aside, before the new one took its place
    (a signal between the two renames): the old output is back where it was and the new one's partial is gone."""
    from heoslice import files

    old, new = tmp_path / "export", partial_path(tmp_path / "export", folder=True)
    old.mkdir()
    (old / "kept.png").write_text("old")
    new.mkdir(exist_ok=True)
    (new / "new.png").write_text("new")
    real_replace, calls = os.replace, []

    def interrupted_replace(source, target):
        calls.append(source)
        if len(calls) == 2:  # the new output's rename
            raise KeyboardInterrupt
        real_replace(source, target)

    monkeypatch.setattr(files.os, "replace", interrupted_replace)
    with pytest.raises(KeyboardInterrupt):
        files.move_into_place(new, old, folder=True)
    monkeypatch.setattr(files.os, "replace", real_replace)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["export"] and (old / "kept.png").read_text() == "old"


def test_a_signal_while_an_export_is_committed_leaves_nothing(project, tmp_path, monkeypatch):
    """An export interrupted while its output is closed and moved into place (the last step) leaves no partial
    beside the output and no output."""
    from heoslice import files
    from heoslice.export import ExportOptions, export_stack

    stack = project / "stack"

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(files, "move_into_place", interrupted)
    monkeypatch.setattr("heoslice.export.base.move_into_place", interrupted)
    folder = tmp_path / "exports"
    folder.mkdir()
    with pytest.raises(KeyboardInterrupt):
        export_stack(stack, "png", folder / "out.zip", ExportOptions())
    assert list(folder.iterdir()) == []
