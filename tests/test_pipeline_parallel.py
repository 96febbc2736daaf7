"""Tests of pipeline/parallel.py: workers, the slice-ahead helper and its shared memory, process settings."""

from __future__ import annotations

import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_pipeline_slice_job import write_mesh

from heoslice import errors, procedural
from heoslice.grading import GradeSpec, RegionSpec
from heoslice.material import DEFAULT_MATERIALS, Material, make_function
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, plane_runs, slice_to_stack

_REUSE_PROBE = """
import os, resource, sys
import numpy as np
from heoslice.pipeline import parallel
if sys.argv[1] == "worker":
    parallel._enter_worker(os.getppid())
faults = []
for _ in range(2):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = np.ones(24 << 20, dtype=np.uint8)
    del block
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(*faults)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt's thresholds are glibc's")
def test_workers_keep_freed_memory_for_the_next_layer():
    """A worker (set up as the pool sets it up) serves a 24 MB block freed by the last layer again
    without new page faults; a plain process keeps glibc's defaults, which fault it in afresh at least
    once (the probe sees the faults when there are some)."""
    def probe(role):
        out = subprocess.run([sys.executable, "-c", _REUSE_PROBE, role], capture_output=True, text=True, check=True)
        return [int(word) for word in out.stdout.split()]

    first, second = probe("worker")
    assert first > 100 and second < 20
    assert max(probe("plain")) > 100


def _graded_spec(**changes) -> SliceSpec:
    """A small graded slice with droplet masks (linear grading, nozzle 0.5 mm, 0.5 mm layers at 150 dpi)."""
    grade = GradeSpec(RegionSpec(nozzle_mm=0.5), make_function("linear"), Material("green", (0, 255, 0)), None,
                      DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    return SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), grade=grade, channels=True, **changes)


def _broken_helper(*args):
    raise RuntimeError("helper broke")


class _Asked:
    """A helper's end of the pipe, as a parent that asks only once the helper has gone through every run."""

    def __init__(self):
        self.sent = []

    def poll(self):
        return False

    def recv(self):
        return None

    def send(self, value):
        self.sent.append(value)


def _run_context(tmp_path, mesh, spec):
    from heoslice.layers import face_z_range, plane_heights
    from heoslice.layers.rasterising import grid_for
    from heoslice.pipeline import RunContext

    loaded = load_mesh(write_mesh(mesh, tmp_path / "part.ply"))
    return RunContext(mesh=loaded, z=plane_heights(loaded.bounds[0, 2], loaded.bounds[1, 2], spec.layer_height_mm),
                      face_range=face_z_range(loaded.vertices, loaded.faces),
                      grid=grid_for(loaded.bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm), spec=spec,
                      directory=tmp_path)


@pytest.mark.parametrize("graded", [False, True])
def test_runs_sliced_ahead_into_shared_memory_are_the_runs_sliced_in_place(tmp_path, graded):
    """What the helper copies into the shared buffer reads back (read-only) as the very contours and
    hierarchy that run_contours makes in place, run by run, and as the layers' solid bits that packed_mask
    makes of them; a buffer too small for the next run stops it after the runs that fit, none cut short;
    run_contours takes a run the context holds instead of slicing it."""
    import mmap

    from heoslice.layers.rasterising import packed_mask
    from heoslice.pipeline import layer_jobs, run_contours
    from heoslice.pipeline.parallel import Ahead, _shared_array, _slice_ahead

    spec = _graded_spec(max_segments=400) if graded else SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0),
                                                                   max_segments=400)
    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), spec)
    runs = plane_runs(context)
    assert len(runs) > 3
    buffer = mmap.mmap(-1, 16 << 20)
    asked = _Asked()
    _slice_ahead(context, runs, buffer, asked)
    ((placed, masks),) = asked.sent
    assert [run for run, _, _ in placed] == [run for run, _ in masks] == runs
    for (run, layout, _), (_, where_bits) in zip(placed, masks):
        expected, _, _ = run_contours(context, *run)
        for name, where in layout:
            got = _shared_array(buffer, where)
            if getattr(expected, name) is None:
                assert got is None and not graded
            else:
                assert not got.flags.writeable and np.array_equal(got, getattr(expected, name))
        jobs = layer_jobs(expected, context.mesh, context.grid, spec, tmp_path, first_layer=run[0])
        bits = _shared_array(buffer, where_bits)
        assert not bits.flags.writeable
        assert np.array_equal(bits, [packed_mask(job.points, job.offsets, context.grid) for job in jobs])
    # room for the first two runs and 64 bytes more: the third does not fit
    two_runs = max(offset + np.dtype(dtype).itemsize * int(np.prod(shape))
                   for _, where in placed[1][1] if where for dtype, shape, offset in [where])
    small = mmap.mmap(-1, two_runs + 64)
    asked = _Asked()
    _slice_ahead(context, runs, small, asked)
    assert [run for run, _, _ in asked.sent[0][0]] == runs[:2] and asked.sent[0][1] == []
    held = run_contours(context, *runs[0])
    ahead = Ahead(contours={runs[0]: (held[0], 0.0, 0.0)})
    assert ahead.run_contours(context, *runs[0])[0] is held[0]


def test_graded_stacks_are_the_same_with_runs_sliced_ahead_or_not(tmp_path, monkeypatch):
    """Graded droplet-mask stacks with workers (and a helper slicing ahead) are byte for byte the serial
    stack, also when every run is sliced ahead (many runs) and when the helper fails."""
    from heoslice.pipeline import parallel

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))

    def layers(name, **changes):
        manifest, _ = slice_to_stack(mesh, tmp_path / name, _graded_spec(**changes))
        return [(e["sha256"], e["channels"]) for e in manifest["layers"]]

    serial = layers("serial", jobs=1)
    assert layers("workers", jobs=2) == serial
    assert layers("many-runs", jobs=2, max_segments=400) == serial

    monkeypatch.setattr(parallel, "_slice_ahead", _broken_helper)
    assert layers("broken-helper", jobs=2) == serial


def test_a_helper_that_fails_or_is_left_makes_nothing_and_leaves_quietly(tmp_path, monkeypatch, capfd):
    """A helper that raises leaves the context as it was; a parent interrupted before it asks ends its helper,
    which leaves without a traceback."""
    from heoslice.pipeline import parallel

    spec = SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), max_segments=400)
    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), spec)
    with pytest.raises(KeyboardInterrupt):
        with parallel._sliced_ahead(context, plane_runs(context)):
            raise KeyboardInterrupt
    assert "Traceback" not in capfd.readouterr().err

    monkeypatch.setattr(parallel, "_slice_ahead", _broken_helper)
    with parallel._sliced_ahead(context, plane_runs(context)) as collect:
        assert collect() == parallel.Ahead()


def test_parallel_slicing_leaves_the_garbage_collector_as_it_found_it(tmp_path):
    """What is frozen for the forks is unfrozen after (nothing left frozen), and a caller that froze its own
    objects finds them frozen still, and no more."""
    import gc

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))
    spec = _graded_spec(jobs=2)
    assert gc.get_freeze_count() == 0
    slice_to_stack(mesh, tmp_path / "a", spec)
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        slice_to_stack(mesh, tmp_path / "b", spec)
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()


def test_a_helper_makes_masks_only_up_to_their_share_of_the_buffer(tmp_path, monkeypatch):
    """Past AHEAD_MASK_BYTES of solid masks the helper stops making them: every run's contours, the masks of
    the runs that fit in that share."""
    import mmap

    from heoslice.pipeline import parallel

    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), _graded_spec(max_segments=400))
    runs = plane_runs(context)
    layers = [stop - start for start, stop in runs[:2]]
    row_bytes = context.grid.height * -(-context.grid.width // 8)
    monkeypatch.setattr(parallel, "AHEAD_MASK_BYTES", sum(layers) * row_bytes)
    asked = _Asked()
    parallel._slice_ahead(context, runs, mmap.mmap(-1, 16 << 20), asked)
    placed, masks = asked.sent[0]
    assert [run for run, _, _ in placed] == runs and [run for run, _ in masks] == runs[:2]


def _silent_helper(*args):
    import signal
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    time.sleep(120)


def test_a_helper_that_does_not_answer_is_left_aside_and_ended(tmp_path, monkeypatch):
    """A helper that neither answers nor ends is waited for at most _AHEAD_WAIT_S (0.3 s here; well within
    30 s, where the helper would still be asleep), its work left to the workers, and it is killed: no
    process is left behind."""
    import multiprocessing
    import time

    from heoslice.pipeline import parallel

    monkeypatch.setattr(parallel, "_slice_ahead", _silent_helper)
    monkeypatch.setattr(parallel, "_AHEAD_WAIT_S", 0.3)
    spec = SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), max_segments=400)
    context = _run_context(tmp_path, procedural.shell_with_island(8.0, 5.0, 2.0, 3), spec)
    started = time.monotonic()
    with parallel._sliced_ahead(context, plane_runs(context)) as collect:
        assert collect() == parallel.Ahead()
    assert time.monotonic() - started < 30
    assert multiprocessing.active_children() == []


def _living(group: int) -> list[int]:
    """Processes of process group ``group`` that have not ended (zombies count as ended)."""
    living = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            state, _, pgrp = (entry / "stat").read_text().rsplit(")", 1)[1].split()[:3]
        except (OSError, ValueError):
            continue
        if int(pgrp) == group and state not in ("Z", "X"):
            living.append(int(entry.name))
    return living


def _files(directory: Path) -> dict:
    """Every file of a directory: name -> (size, modification time in ns)."""
    return {entry.name: (entry.stat().st_size, entry.stat().st_mtime_ns) for entry in directory.iterdir()}


@pytest.fixture(scope="module")
def slow_slice(tmp_path_factory):
    """A graded slice with droplet masks that takes a few seconds on two workers (480 layers), as arguments."""
    model = tmp_path_factory.mktemp("slow") / "ball.ply"
    procedural.shell_with_island(12.0, 8.0, 3.0, 4).export(model)
    return [str(model), "--layer", "0.05", "--dpi", "400", "-j", "2", "--grade", "linear", "--channels",
            "--nozzle", "0.3"]


def _started(slow_slice, directory: Path, until_files: int, at_least_s: float = 0.0):
    """`heoslice slice` in a session of its own, once ``directory`` holds ``until_files`` files and
    ``at_least_s`` have passed."""
    process = subprocess.Popen([sys.executable, "-m", "heoslice", "slice", *slow_slice, "-o", str(directory)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    began = time.monotonic()
    while time.monotonic() - began < 60 and process.poll() is None:
        count = len(list(directory.iterdir())) if directory.is_dir() else 0
        if count >= until_files and time.monotonic() - began >= at_least_s:
            break
        time.sleep(0.02)
    assert process.poll() is None, "the slice ended before it could be stopped"
    return process


@pytest.mark.parametrize("moment", ["loading", "first layer", "workers"])
def test_a_killed_slice_leaves_no_process_and_no_writer_behind(tmp_path, slow_slice, moment):
    """SIGKILL of `heoslice slice` while it loads, renders its first layer (the helper slicing ahead) or has
    its workers writing: 1 s later no process of it is alive, and the stack directory does not change after."""
    directory = tmp_path / "stack"
    until_files, at_least_s = {"loading": (0, 0.3), "first layer": (1, 0.0), "workers": (100, 0.0)}[moment]
    process = _started(slow_slice, directory, until_files, at_least_s)
    process.kill()
    process.wait()
    time.sleep(1.0)
    assert _living(process.pid) == []
    before = _files(directory) if directory.is_dir() else {}
    time.sleep(0.5)
    assert (_files(directory) if directory.is_dir() else {}) == before
    assert "manifest.json" not in before and not [name for name in before if name.endswith(".tmp")]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_ends_a_slice_with_one_line_and_nothing_left_running(tmp_path, slow_slice, signum):
    """SIGINT (Ctrl-C), SIGTERM and SIGHUP to a slicing `heoslice slice` with its workers writing: it ends
    with 128 + the signal's number and one line, no traceback, no process of it left, no manifest."""
    if signum != signal.SIGINT and not hasattr(errors, "Interrupted"):
        pytest.skip("SIGTERM and SIGHUP end the command as Ctrl-C does only with heoslice.errors.Interrupted")
    directory = tmp_path / "stack"
    process = _started(slow_slice, directory, 100)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=30)
    lines = stderr.decode().strip().splitlines()
    assert process.returncode == 128 + signum and len(lines) == 1 and "interrupted" in lines[0], lines
    time.sleep(0.5)
    assert _living(process.pid) == []
    assert not (directory / "manifest.json").exists()


def test_a_workers_error_reaches_the_parent_and_a_dead_worker_is_reported(tmp_path, monkeypatch):
    """An error raised in a worker is raised in the parent as itself (one-line errors stay one line); a worker
    that dies without answering is a RuntimeError saying so; either way no worker is left running."""
    import multiprocessing
    import os

    from heoslice.errors import OutputError
    from heoslice.pipeline import parallel

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))
    spec = SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), jobs=2, max_segments=400)
    parent = os.getpid()

    def failing(self, context, start, stop, cache):
        if os.getpid() != parent:
            raise OutputError("stack: cannot write (no space left on device)")

    monkeypatch.setattr(parallel.Ahead, "slice_run", failing)
    with pytest.raises(OutputError, match="^stack: cannot write"):
        slice_to_stack(mesh, tmp_path / "a", spec)
    assert multiprocessing.active_children() == []

    monkeypatch.setattr(parallel.Ahead, "slice_run", lambda *args: os._exit(3))
    with pytest.raises(RuntimeError, match="slice worker ended unexpectedly"):
        slice_to_stack(mesh, tmp_path / "b", spec)
    assert multiprocessing.active_children() == []
