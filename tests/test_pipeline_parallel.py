"""Tests of pipeline/parallel.py: workers and their output, signals and dying with the parent, process settings."""

from __future__ import annotations

import multiprocessing
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_pipeline_slice_job import write_mesh

from heoslice import errors, procedural
from heoslice.grading import GradeSpec, RegionSpec
from heoslice.material import DEFAULT_MATERIALS, Material, make_function
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack

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


@pytest.mark.parametrize("halftone", ["ordered", "blue-noise", "error-diffusion"])
def test_graded_stacks_made_with_workers_are_the_serial_stack(tmp_path, halftone):
    """Graded droplet-mask stacks made with workers are byte for byte the serial stack, also with many runs,
    whatever the halftone (error diffusion's error, carried from layer to layer, starts afresh at the same
    layers however the runs are shared out among processes)."""
    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))

    def layers(name, **changes):
        manifest, _ = slice_to_stack(mesh, tmp_path / name, _graded_spec(halftone=halftone, **changes))
        return [(e["sha256"], e["channels"]) for e in manifest["layers"]]

    serial = layers("serial", jobs=1)
    assert layers("workers", jobs=2) == serial
    many = layers("many-runs", jobs=2, max_segments=400)
    # the diffused error starts afresh where a run of planes starts: runs of fewer segments start elsewhere
    assert many == (layers("many-runs-serial", jobs=1, max_segments=400) if halftone == "error-diffusion"
                    else serial)


def test_parallel_slicing_leaves_the_garbage_collector_as_it_found_it(tmp_path):
    """What is frozen for the forks is unfrozen after (nothing left frozen), and a caller that froze its own
    objects finds them frozen still, and no more. (Frozen objects the slice lets die, such as a cache's entry it
    replaces, leave the permanent generation: the count may fall by those few, never rise, and an unfreeze of
    the caller's objects would take it to the objects heoslice froze itself.)"""
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
        assert frozen - 100 <= gc.get_freeze_count() <= frozen
    finally:
        gc.unfreeze()


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


def _started(slow_slice, directory: Path, until_files: int, at_least_s: float = 0.0, env: dict | None = None):
    """`heoslice slice` in a session of its own (with environment ``env``), once ``directory`` holds
    ``until_files`` files and ``at_least_s`` have passed."""
    process = subprocess.Popen([sys.executable, "-m", "heoslice", "slice", *slow_slice, "-o", str(directory)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True, env=env)
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
    """SIGKILL of `heoslice slice` while it loads, renders its first layer or has its workers writing: 1 s
    later no process of it is alive, and the stack directory does not change after."""
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
    from heoslice.pipeline import runs

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))
    spec = SliceSpec(layer_height_mm=0.5, dpi=(150.0, 150.0), jobs=2, max_segments=400)
    parent, slice_run = os.getpid(), runs.slice_run

    def in_workers(fail):
        """slice_run as it is in the parent (its first layer), and ``fail()`` in the workers."""
        return lambda *args: slice_run(*args) if os.getpid() == parent else fail()

    def no_space():
        raise OutputError("stack: cannot write (no space left on device)")

    monkeypatch.setattr(runs, "slice_run", in_workers(no_space))
    with pytest.raises(OutputError, match="^stack: cannot write"):
        slice_to_stack(mesh, tmp_path / "a", spec)
    assert multiprocessing.active_children() == []

    monkeypatch.setattr(runs, "slice_run", in_workers(lambda: os._exit(3)))
    with pytest.raises(RuntimeError, match="slice worker ended unexpectedly"):
        slice_to_stack(mesh, tmp_path / "b", spec)
    assert multiprocessing.active_children() == []


def test_a_run_sent_to_a_worker_that_has_ended_is_the_dead_worker_error():
    """Sending a run to a worker that already ended (its end of the pipe closed: killed between two runs) is the
    one-line RuntimeError of a dead worker, with its exit status, not a BrokenPipeError from the pipe."""
    import os
    from multiprocessing import get_context

    from heoslice.pipeline import parallel

    ours, theirs = get_context("fork").Pipe()
    process = get_context("fork").Process(target=os._exit, args=(5,))
    process.start()
    process.join()
    theirs.close()
    with pytest.raises(RuntimeError, match=r"^a slice worker ended unexpectedly \(exit status 5\)$"):
        parallel._give(ours, process, (0, 1))
    ours.close()


# --- the portable path (no fork, no prctl, no glibc call) ------------------------------------------------------

def test_the_portable_path_is_taken_where_the_fast_one_cannot_run_or_when_forced(monkeypatch):
    """HEOSLICE_PORTABLE=1 forces it; another platform, a C library other than glibc or no fork choose it; Linux
    with glibc and fork, unforced (or set to 0), takes the fast path."""
    import multiprocessing

    from heoslice.pipeline import parallel

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(platform, "libc_ver", lambda: ("glibc", "2.36"))
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["fork", "spawn", "forkserver"])
    monkeypatch.delenv(parallel.PORTABLE_VARIABLE, raising=False)
    assert not parallel.portable()
    monkeypatch.setenv(parallel.PORTABLE_VARIABLE, "0")
    assert not parallel.portable()
    monkeypatch.setenv(parallel.PORTABLE_VARIABLE, "1")
    assert parallel.portable()
    monkeypatch.delenv(parallel.PORTABLE_VARIABLE)
    for change in (lambda: monkeypatch.setattr(sys, "platform", "darwin"),
                   lambda: monkeypatch.setattr(platform, "libc_ver", lambda: ("", "")),
                   lambda: monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])):
        with monkeypatch.context() as inner:
            inner.setattr(sys, "platform", "linux")
            change()
            assert parallel.portable()


def test_portable_path_stacks_are_byte_for_byte_the_fast_paths(tmp_path, monkeypatch):
    """Forced, the portable path starts its workers by spawn only (no fork; no C library call in this process) and
    writes the same graded droplet-mask stack, file for file, as the fast path and as one process."""
    import ctypes
    import hashlib

    from heoslice.pipeline import parallel

    mesh = load_mesh(write_mesh(procedural.shell_with_island(8.0, 5.0, 2.0, 3), tmp_path / "m.ply"))

    def files(name, **changes):
        slice_to_stack(mesh, tmp_path / name, _graded_spec(**changes))
        return {path.name: hashlib.sha256(path.read_bytes()).hexdigest() for path in (tmp_path / name).iterdir()}

    fast = files("fast", jobs=2, max_segments=400)
    methods, real_context = [], parallel.get_context

    def recording(method):
        methods.append(method)
        return real_context(method)

    def no_c_library(*args, **kwargs):
        raise AssertionError("the portable path called the C library")

    monkeypatch.setenv(parallel.PORTABLE_VARIABLE, "1")
    monkeypatch.setattr(parallel, "get_context", recording)
    monkeypatch.setattr(ctypes, "CDLL", no_c_library)
    portable = files("portable", jobs=2, max_segments=400)
    assert methods and set(methods) == {"spawn"}
    assert portable == fast == files("serial", jobs=1)


def test_portable_workers_end_with_a_killed_or_signalled_slice(tmp_path, slow_slice):
    """On the forced portable path, SIGKILL of `heoslice slice` with its workers writing leaves no process of it
    alive 1 s later and the directory unchanged after; SIGTERM ends it with one line, exit 143, no process left."""
    import os

    env = {**os.environ, "HEOSLICE_PORTABLE": "1"}
    process = _started(slow_slice, tmp_path / "killed", 100, env=env)
    process.kill()
    process.wait()
    time.sleep(1.0)
    assert _living(process.pid) == []
    before = _files(tmp_path / "killed")
    time.sleep(0.5)
    assert _files(tmp_path / "killed") == before and "manifest.json" not in before
    process = _started(slow_slice, tmp_path / "terminated", 100, env=env)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=30)
    lines = stderr.decode().strip().splitlines()
    assert process.returncode == 143 and len(lines) == 1 and "interrupted" in lines[0], lines
    time.sleep(0.5)
    assert _living(process.pid) == []


def test_worker_count_needs_no_affinity_call(monkeypatch):
    """One worker per usable core: the affinity where the platform has it (Linux), else the core count (macOS has
    no sched_getaffinity)."""
    import os

    assert SliceSpec(jobs=0).worker_count() == len(os.sched_getaffinity(0))
    monkeypatch.delattr(os, "sched_getaffinity")
    monkeypatch.setattr(os, "cpu_count", lambda: 3)
    assert SliceSpec(jobs=0).worker_count() == 3 and SliceSpec(jobs=2).worker_count() == 2
def test_ordered_map_keeps_the_items_order_over_workers():
    """ordered_map yields function(item) in the items' order whether the items run in forked workers or here,
    and its workers are gone once it is done."""
    from heoslice.pipeline.parallel import ordered_map

    def slow_square(item: int) -> tuple[int, int]:
        import time

        time.sleep(0.01 * ((7 * item) % 3))  # results arrive out of order
        return item, os.getpid()

    results = list(ordered_map(slow_square, range(25), workers=2))
    assert [item for item, _ in results] == list(range(25))
    assert os.getpid() not in {pid for _, pid in results}
    assert [item for item, _ in ordered_map(slow_square, range(5), workers=1)] == list(range(5))
    assert not multiprocessing.active_children()


def test_ordered_map_in_larger_batches_keeps_the_order_and_the_round_trips_few():
    """With ``most_batched``, ordered_map yields the same results in the items' order (a batch that does not divide
    the count too), each batch computed whole in one worker, and its workers are gone once it is done."""
    from heoslice.pipeline.parallel import batch_size, ordered_map

    count = 2000
    size = batch_size(count, 2, 40)
    assert size == 40
    results = list(ordered_map(lambda item: (item * item, os.getpid()), range(count), workers=2, most_batched=40))
    assert [value for value, _ in results] == [item * item for item in range(count)]
    assert all(len({pid for _, pid in results[start:start + size]}) == 1 for start in range(0, count, size))
    assert os.getpid() not in {pid for _, pid in results}
    assert list(ordered_map(lambda item: -item, range(3), workers=2, most_batched=10)) == [0, -1, -2]
    assert not multiprocessing.active_children()


def test_ordered_map_raises_a_workers_error_and_ends_the_workers():
    """An exception in a worker reaches the caller as itself, with the worker's traceback as a note."""
    from heoslice.pipeline.parallel import ordered_map

    def fail_on_three(item: int) -> int:
        if item == 3:
            raise ValueError("item three")
        return item

    with pytest.raises(ValueError, match="item three") as raised:
        list(ordered_map(fail_on_three, range(8), workers=2))
    assert any("in a worker" in note for note in raised.value.__notes__)
    assert not multiprocessing.active_children()


def test_ordered_map_batches_keep_the_order_and_stay_small():
    """Items travel in batches (batch_size: at least 16 a worker, at most 8 items each): over 300 items whose
    results arrive out of order, every result comes back once, in order, from the workers; a failure in the
    middle of a batch is raised as itself."""
    from heoslice.pipeline.parallel import batch_size, ordered_map

    assert batch_size(300, 2) == 8 and batch_size(200, 2) == 6 and batch_size(20, 2) == 1
    assert all(1 <= batch_size(n, w) <= 8 and (batch_size(n, w) == 1 or n // batch_size(n, w) >= 16 * w)
               for n in range(1, 2000, 37) for w in (1, 2, 3, 8))

    def uneven(item: int) -> tuple[int, int]:
        import time

        time.sleep(0.002 * ((7 * item) % 3))
        if item == 205:
            raise KeyError("item 205")
        return item, os.getpid()

    results = list(ordered_map(uneven, range(200), workers=2))
    assert [item for item, _ in results] == list(range(200))
    assert os.getpid() not in {pid for _, pid in results}
    with pytest.raises(KeyError, match="item 205"):
        list(ordered_map(uneven, range(300), workers=2))
    assert not multiprocessing.active_children()


def test_a_started_child_no_pool_kept_does_not_hold_up_the_exit(tmp_path):
    """A worker started but not yet kept by its pool when Ctrl-C arrives (here: started and left) is killed when
    the command exits: the exit takes well under the worker's 30 s of work, and the worker is gone (before,
    multiprocessing's exit handler sent it SIGTERM, which workers ignore, and waited: a lab user's `verify` hung
    after 'interrupted')."""
    script = tmp_path / "orphan.py"
    script.write_text("import sys, time\n"
                      "from heoslice.pipeline.parallel import _enter_worker, _start\n"
                      "child = _start(_enter_worker, time.sleep, 30)\n"
                      "print(child.pid, flush=True)\n"
                      "sys.exit(130)\n")
    started = time.monotonic()
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=25)
    assert done.returncode == 130, done.stderr
    assert time.monotonic() - started < 10
    pid = int(done.stdout.strip())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
