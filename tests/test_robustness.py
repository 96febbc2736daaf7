"""Robustness end to end: killed runs, full disks, unwritable and read-only outputs, hostile files, the corpus.

Each test runs the real command (``python -m heoslice`` in a subprocess where the
process itself must be killed or limited, in-process otherwise) and checks the
guarantees of the README: no complete-looking stack is left by a failed run,
``verify`` rejects it, ``--force`` repairs it, and every failure is one line with
a documented exit status, never a traceback.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_data_dir

from heoslice import procedural
from heoslice.errors import EXIT_BUG, EXIT_INPUT, EXIT_OUTPUT, EXIT_VERIFY
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.stack import MANIFEST, read_manifest, verify_stack

#: Thin layers (1,200 of the 60 mm vase), so that a kill after 150 layer files lands with about a quarter of a
#: second of the slice still to go (at 0.2 mm, 300 layers, the last 150 took 32 ms, and a busy CI machine once let
#: a slice finish first).
LAYER_MM, DPI = 0.05, 200
SLICE_ARGS = ["--dpi", str(DPI), "--layer", str(LAYER_MM), "-j", "2"]
LAYERS = round(60 / LAYER_MM)  # the procedural vase is 60 mm tall


@pytest.fixture(scope="module")
def vase_model(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("model") / "vase.ply"
    procedural.vase().export(path)
    return path


@pytest.fixture(scope="module")
def reference(vase_model, tmp_path_factory) -> dict:
    """The manifest of an uninterrupted slice, to compare repaired stacks with."""
    directory = tmp_path_factory.mktemp("reference") / "stack"
    manifest, _ = slice_to_stack(load_mesh(vase_model), directory, SliceSpec(layer_height_mm=LAYER_MM, dpi=(DPI, DPI)))
    return manifest


def heoslice(*args, **popen) -> subprocess.Popen:
    """Start ``python -m heoslice ARGS`` in its own process group (so it and its workers can be killed)."""
    return subprocess.Popen([sys.executable, "-m", "heoslice", *map(str, args)], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_child_setup(popen.pop("preexec_fn", None)), **popen)


def _child_setup(extra=None):
    """In the child: SIGINT as a terminal delivers it (even when the test runner was started with it
    ignored), then ``extra`` (e.g. a resource limit)."""

    def setup() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if extra is not None:
            extra()

    return setup


def layer_count(directory: Path, newer_than: float = 0.0) -> int:
    try:
        return sum(1 for p in directory.glob("layer_*.tif") if p.stat().st_mtime > newer_than)
    except FileNotFoundError:
        return 0


def kill_when(process: subprocess.Popen, ready, timeout: float = 60.0) -> bool:
    """SIGKILL the process group as soon as ``ready()``; True when it was still running then."""
    deadline = time.monotonic() + timeout
    while process.poll() is None and time.monotonic() < deadline and not ready():
        time.sleep(0.002)
    running = process.poll() is None
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)
    process.communicate()
    return running


def assert_repaired(run_cli, model: Path, directory: Path, reference: dict) -> None:
    """A rerun with --force gives a stack that verifies clean, layer for layer the uninterrupted one."""
    code, _, err = run_cli("slice", model, "-o", directory, "--force", *SLICE_ARGS)
    assert code == 0, err
    report = verify_stack(directory)
    assert report.ok, report.problems
    assert [e["sha256"] for e in report.manifest["layers"]] == [e["sha256"] for e in reference["layers"]]


@pytest.mark.parametrize("after_files", [0, 1, 150])
def test_sigkill_during_slice_leaves_a_rejected_stack_that_force_repairs(
        tmp_path, vase_model, reference, run_cli, after_files):
    """SIGKILL after N layer files exist: no manifest, verify rejects (exit 4), --force rerun verifies clean."""
    directory = tmp_path / "stack"
    process = heoslice("slice", vase_model, "-o", directory, *SLICE_ARGS)
    ready = (lambda: directory.is_dir()) if after_files == 0 else (lambda: layer_count(directory) >= after_files)
    assert kill_when(process, ready), "slice finished before it could be killed"
    assert not (directory / MANIFEST).exists()
    assert not verify_stack(directory).ok
    code, out, err = run_cli("verify", directory)
    assert code == EXIT_VERIFY and "no manifest.json" in out
    assert_repaired(run_cli, vase_model, directory, reference)


def test_sigkill_during_force_rewrite_of_a_good_stack(tmp_path, vase_model, reference, run_cli):
    """Killing a --force rerun over a complete stack never leaves the old manifest describing mixed layers."""
    directory = tmp_path / "stack"
    assert run_cli("slice", vase_model, "-o", directory, *SLICE_ARGS)[0] == 0
    started = time.time()
    time.sleep(0.01)
    process = heoslice("slice", vase_model, "-o", directory, "--force", *SLICE_ARGS)
    assert kill_when(process, lambda: not (directory / MANIFEST).exists()
                     and layer_count(directory, started) >= 50)
    assert not verify_stack(directory).ok
    assert_repaired(run_cli, vase_model, directory, reference)


def test_sigkill_at_random_moments_never_leaves_a_bad_stack_that_verifies(tmp_path, vase_model, reference, run_cli):
    """At any kill moment, either verify rejects the directory or the stack is complete and identical."""
    directory = tmp_path / "stack"
    for delay in np.random.default_rng(3).uniform(0.5, 2.5, 2):
        process = heoslice("slice", vase_model, "-o", directory, "--force", *SLICE_ARGS)
        until = time.monotonic() + delay
        kill_when(process, lambda: time.monotonic() > until)
        report = verify_stack(directory)
        if (directory / MANIFEST).exists() and report.ok:
            assert [e["sha256"] for e in report.manifest["layers"]] == [e["sha256"] for e in reference["layers"]]
        else:
            assert not report.ok
    assert_repaired(run_cli, vase_model, directory, reference)


def test_ctrl_c_is_one_line_exit_130_and_no_stack(tmp_path, vase_model, run_cli):
    """SIGINT to the whole process group (Ctrl-C in a terminal): one line 'heoslice: interrupted' saying the folder
    holds an incomplete stack and to rerun with --force, exit 130, no worker tracebacks, no manifest; `verify` on
    the folder says the same (exit 4)."""
    directory = tmp_path / "stack"
    process = heoslice("slice", vase_model, "-o", directory, *SLICE_ARGS, stdin=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while process.poll() is None and layer_count(directory) < 20 and time.monotonic() < deadline:
        time.sleep(0.002)
    assert process.poll() is None, "slice finished before it could be interrupted"
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"heoslice: interrupted: {directory}: incomplete stack"), err
    assert "run that slice again with --force" in lines[0]
    assert not (directory / MANIFEST).exists() and not verify_stack(directory).ok
    code, out, _ = run_cli("verify", directory)
    assert code == EXIT_VERIFY and "incomplete stack" in out and "again with --force" in out


def one_error_line(stderr: str) -> str:
    """The single 'heoslice: error:' line of a failed run (warnings may precede it), never a traceback."""
    assert "Traceback" not in stderr
    errors = [line for line in stderr.splitlines() if line.startswith("heoslice: error:")]
    assert len(errors) == 1 and stderr.rstrip().splitlines()[-1] == errors[0], stderr
    return errors[0]


def test_file_size_limit_is_one_line_exit_3(tmp_path, vase_model, run_cli):
    """With RLIMIT_FSIZE below a layer's size the run fails with one line, exit 3, and verify rejects."""
    directory = tmp_path / "stack"

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))

    process = heoslice("slice", vase_model, "-o", directory, *SLICE_ARGS, preexec_fn=limit)
    _, err = process.communicate(timeout=120)
    assert process.returncode == EXIT_OUTPUT
    assert "cannot write (file size limit exceeded)" in one_error_line(err)
    assert not verify_stack(directory).ok


@contextlib.contextmanager
def mounted(*options: str):
    """A fresh directory with a file system mounted on it (root only); skips the test when mounting fails."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting needs root")
    point = Path(tempfile.mkdtemp(prefix="heoslice-mount-"))
    done = subprocess.run(["mount", *options, str(point)], capture_output=True)
    if done.returncode != 0:
        point.rmdir()
        pytest.skip(f"cannot mount here: {done.stderr.decode().strip()}")
    try:
        yield point
    finally:
        subprocess.run(["umount", "-l", str(point)], capture_output=True)
        point.rmdir()


def test_disk_full_is_one_line_exit_3(vase_model, run_cli):
    """On a 256 KiB tmpfs the slice stops with 'no space left on device', exit 3; verify rejects what is left."""
    with mounted("-t", "tmpfs", "-o", "size=256k", "tmpfs") as point:
        directory = point / "stack"
        code, _, err = run_cli("slice", vase_model, "-o", directory, *SLICE_ARGS)
        assert code == EXIT_OUTPUT
        assert "no space left on device" in one_error_line(err)
        assert not verify_stack(directory).ok


def test_read_only_file_system_is_one_line_exit_3(vase_model, run_cli):
    """A read-only mount: creating the stack or writing into an existing directory fails with one line, exit 3."""
    source = Path(tempfile.mkdtemp(prefix="heoslice-ro-"))
    try:
        (source / "existing").mkdir()
        with mounted("--bind", "-o", "ro", str(source)) as point:
            for target, expected in ((point / "new", "Read-only file system"),
                                     (point / "existing", "not writable")):
                code, _, err = run_cli("slice", vase_model, "-o", target, *SLICE_ARGS)
                assert code == EXIT_OUTPUT and expected in one_error_line(err)
    finally:
        shutil.rmtree(source)


def test_unwritable_directory_is_one_line_exit_3(tmp_path, vase_model, run_cli):
    """A directory the user cannot write (immutable for root, mode 555 otherwise): one line, exit 3."""
    locked = tmp_path / "locked"
    locked.mkdir()
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(locked)]).returncode != 0:
            pytest.skip("cannot make a directory unwritable for root here")
        undo = ["chattr", "-i", str(locked)]
    else:
        locked.chmod(0o555)
        undo = ["chmod", "755", str(locked)]
    try:
        for target in (locked, locked / "sub"):
            code, _, err = run_cli("slice", vase_model, "-o", target, *SLICE_ARGS)
            assert code == EXIT_OUTPUT, err
            one_error_line(err)
    finally:
        subprocess.run(undo)


def test_hostile_header_in_a_subprocess_stays_under_100_mb(tmp_path):
    """`heoslice info` on a PLY declaring 10**12 vertices exits 2 with one line; peak RSS < 100 MB."""
    path = tmp_path / "hostile.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n"
                     b"property float x\nproperty float y\nproperty float z\nelement face 1000000000000\n"
                     b"property list uchar int vertex_indices\nend_header\n" + bytes(64))
    probe = ("import resource, subprocess, sys; "
             "r = subprocess.run([sys.executable, '-m', 'heoslice', 'info', sys.argv[1]], capture_output=True, "
             "text=True); print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); "
             "print(r.stderr, end='')")
    done = subprocess.run([sys.executable, "-c", probe, str(path)], capture_output=True, text=True, timeout=60)
    first, *rest = done.stdout.splitlines()
    code, peak_kib = (int(v) for v in first.split())
    assert code == EXIT_INPUT
    assert "truncated or corrupt PLY" in one_error_line("\n".join(rest))
    assert peak_kib < 100 * 1024


def test_debug_shows_the_traceback_only_when_asked(tmp_path, monkeypatch, run_cli):
    """A bug is one 'internal error' line (exit 1); --debug adds the traceback. User errors too."""
    import heoslice.cli.verify as verify_module

    def broken(directory, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(verify_module, "verify_stack", broken)
    tmp_path.joinpath("stack").mkdir()
    code, _, err = run_cli("verify", tmp_path / "stack")
    assert code == EXIT_BUG and "Traceback" not in err
    assert err.strip() == ("heoslice: internal error: RuntimeError: boom "
                           "(rerun with --debug and report the traceback)")
    code, _, err = run_cli("--debug", "verify", tmp_path / "stack")
    assert code == EXIT_BUG and "Traceback (most recent call last)" in err and "RuntimeError: boom" in err
    code, _, err = run_cli("--debug", "info", tmp_path / "absent.ply")
    assert code == EXIT_INPUT and "Traceback" in err and "no such file" in err


# --- heoslice verify, the command ----------------------------------------------------------------


def test_verify_command_clean_and_with_mesh(tmp_path, vase_model, reference, run_cli):
    """A good stack: exit 0; --mesh adds volume (within 1 %) and layer heights; --json has the same facts."""
    directory = tmp_path / "stack"
    assert run_cli("slice", vase_model, "-o", directory, *SLICE_ARGS)[0] == 0
    code, out, err = run_cli("verify", directory, "--mesh", vase_model)
    assert code == 0, out + err
    assert out.startswith(f"{directory}: OK, {LAYERS} layers")
    code, out, _ = run_cli("verify", directory, "--mesh", vase_model, "--json")
    summary = json.loads(out)
    assert code == 0 and summary["ok"] and summary["problems"] == [] and summary["layers"] == LAYERS
    mesh = load_mesh(vase_model)
    assert summary["mesh"]["watertight"] is True
    assert abs(summary["mesh"]["relative_volume_difference"]) < 0.01
    assert summary["mesh"]["z_range_mm"] == pytest.approx(mesh.bounds[:, 2].tolist())


def test_verify_command_flags_a_wrong_mesh(tmp_path, vase_model, run_cli):
    """Against another (watertight) mesh: volume and layer-height problems, one line each, exit 4."""
    directory = tmp_path / "stack"
    assert run_cli("slice", vase_model, "-o", directory, *SLICE_ARGS)[0] == 0
    other = tmp_path / "sphere.ply"
    procedural.sphere(radius=20.0).export(other)
    code, out, err = run_cli("verify", directory, "--mesh", other)
    assert code == EXIT_VERIFY
    lines = out.splitlines()
    assert any("differs from the mesh volume" in line for line in lines)
    assert any("z-range" in line and f"needs {round(40 / LAYER_MM)}" in line for line in lines)  # a 40 mm sphere
    assert "sha256 differs" in err and one_error_line(err).endswith("problem(s); do not print this stack")


def test_verify_command_open_mesh_volume_is_a_warning(tmp_path, run_cli):
    """For a mesh that is not watertight a volume difference only warns (exit 0 when nothing else is wrong)."""
    box = procedural.box(extents=(10.0, 10.0, 10.0))
    model = tmp_path / "box.ply"
    box.export(model)
    directory = tmp_path / "stack"
    assert run_cli("slice", model, "-o", directory, "--layer", "1", "--dpi", "100")[0] == 0
    import trimesh

    opened = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)  # drop the bottom: open
    open_model = tmp_path / "open.ply"
    opened.export(open_model)
    code, out, err = run_cli("verify", directory, "--mesh", open_model)
    assert code == 0, out + err
    assert "not watertight" in err and "differs from the mesh volume" in err


def test_verify_command_missing_directory_is_input_error(tmp_path, run_cli):
    """A STACK path that does not exist is a bad argument: one line, exit 2."""
    code, _, err = run_cli("verify", tmp_path / "nope")
    assert code == EXIT_INPUT and "no such directory" in one_error_line(err)


# --- the shared corpus ----------------------------------------------------------------------------


def corpus() -> list[Path]:
    folder = shared_data_dir()
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".ply", ".stl", ".obj", ".off"))


def coarse_options(model: Path) -> list[str]:
    """About 20 layers of at most about 150 px across, whatever the mesh's size or units."""
    try:
        mesh = load_mesh(model)
    except Exception:  # noqa: BLE001 - the command itself must report it; options do not matter then
        return ["--layer", "1", "--dpi", "50"]
    extent = mesh.bounds[1] - mesh.bounds[0]
    layer = max(float(extent[2]) / 20.0, 1e-6)
    dpi = 150.0 * 25.4 / max(float(extent[:2].max()), 1e-6)
    return ["--layer", f"{layer:.6g}", "--dpi", f"{dpi:.6g}", "--margin", "0", "-j", "1"]


@pytest.mark.shared_data
@pytest.mark.parametrize("model", corpus(), ids=lambda p: str(p.relative_to(shared_data_dir())))
def test_corpus_slices_to_a_verified_stack_or_fails_in_one_line(tmp_path, model, run_cli):
    """Every shared mesh either slices to a stack verify accepts (exit 0) or fails with one error line, exit 2."""
    directory = tmp_path / "stack"
    code, _, err = run_cli("slice", model, "-o", directory, *coarse_options(model))
    assert code in (0, EXIT_INPUT), err
    assert "Traceback" not in err and "internal error" not in err
    if code == 0:
        report = verify_stack(directory)
        assert report.ok, report.problems
        assert read_manifest(directory)["complete"] is True
    else:
        one_error_line(err)
        assert not (directory / MANIFEST).exists()


_ENVIRONMENT_PROBE = """
import atexit, os, sys
def report():
    import numpy._core.multiarray as multiarray
    huge = multiarray._set_madvise_hugepage(True)  # returns the setting numpy loaded with
    print(os.environ.get("OPENBLAS_NUM_THREADS"), os.environ.get("NUMPY_MADVISE_HUGEPAGE"), huge)
atexit.register(report)
from heoslice.cli import main
print("numpy" in sys.modules)
sys.argv = ["heoslice", "--version"]
main()
"""


@pytest.mark.parametrize("given, expected", [(None, "1 0 False"), ("3", "3 3 True")])
def test_the_command_sets_numpys_environment_unless_told_otherwise(given, expected):
    """The console command sets OPENBLAS_NUM_THREADS to 1 (heoslice makes no BLAS call worth threads; the pools
    only spin) and NUMPY_MADVISE_HUGEPAGE to 0 (huge pages cost a large mesh's load more system time than they
    save) before numpy is loaded, so numpy loads with them; a value the user set is kept."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "NUMPY_MADVISE_HUGEPAGE")}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = env["NUMPY_MADVISE_HUGEPAGE"] = given
    out = subprocess.run([sys.executable, "-c", _ENVIRONMENT_PROBE], capture_output=True, text=True, env=env,
                         check=True)
    lines = out.stdout.split("\n")
    assert lines[0] == "False" and lines[-2] == expected


@pytest.mark.parametrize("options, needle", [
    (["--offsets", "1000000000"], "--offsets"), (["--nozzle", "1e-9"], "--nozzle"),
    (["--depth", "1e9"], "--depth"), (["--depth", "1e308"], "--depth"),
    (["--materials", "/dev/zero"], "/dev/zero"),
])
def test_absurd_grading_options_are_refused_in_bounded_time_and_memory(tmp_path, options, needle):
    """--offsets 1e9, --nozzle 1e-9 and --depth 1e9 (5e9 sub-regions: 37 GiB of bands), --depth 1e308 (an
    overflow) and --materials /dev/zero (an endless read) are one line, exit 2, in start-up time and memory."""
    from test_mesh_limits import assert_one_line_refusal, run_bounded

    model = tmp_path / "box.ply"
    procedural.box((5.0, 5.0, 2.0)).export(model)
    result = run_bounded("--no-config", "slice", model, "-o", tmp_path / "s", "--layer", "0.5", "--dpi", "100",
                         "--grade", "linear", *options, timeout=60)
    assert_one_line_refusal(result, needle, rss_mib=300.0)
    assert not (tmp_path / "s" / MANIFEST).exists()
