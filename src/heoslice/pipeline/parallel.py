"""The slice pipeline's process machinery, all in one place: worker processes, the slice-ahead helper and the
memory it shares, the allocator and collector settings, BLAS threads, and dying with the parent.

How a slice runs on several cores (:func:`run_all`): the first layer is rendered in this process, so that
what it loads (compiled kernels, codecs) is loaded once and inherited by every fork; meanwhile a forked helper
slices and chains the next runs of planes into an anonymous shared mapping (graded slices only, whose first
layer takes long). Then ``workers`` processes are forked, each handed runs of planes over its own pipe, at
most two at a time; they write their layers and send back what they wrote. Every child ignores the signals
that end a run (Ctrl-C, SIGTERM, SIGHUP: the parent reports them) and is killed by the kernel when the parent
ends however it ends (``PR_SET_PDEATHSIG``), so nothing writes into the stack after the parent has gone.

Importing this module loads nothing but the standard library, so that the ``heoslice`` command can set its
process's BLAS threads (:func:`single_blas_thread`) before numpy loads; numpy and the pipeline's stages are
imported by the functions that use them.
"""

from __future__ import annotations

import ctypes
import gc
import mmap
import os
import signal
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from multiprocessing import get_context
from multiprocessing.connection import wait as wait_for
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from heoslice.layers.contours import Contours
    from heoslice.pipeline.layer_job import PipelineCache
    from heoslice.pipeline.runs import RunContext, RunResult, SlicedRun

#: Signals that end a slice: the parent turns them into one line; its children ignore them.
ENDING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Most bytes a helper makes ahead (shared memory, touched only as written), and of them at most
#: AHEAD_MASK_BYTES of solid masks (a 15 MP organ's run of masks is 32 MB: each worker maps what it reads).
AHEAD_BYTES = 256 << 20
AHEAD_MASK_BYTES = 64 << 20
#: Longest wait (s) for a helper to answer, and then to end, before it is left aside (and killed).
_AHEAD_WAIT_S = 10.0
#: Runs handed to one worker at a time: the next is waiting when it finishes one.
_RUNS_IN_FLIGHT = 2
#: prctl(2) option: the signal this process gets when its parent ends (linux/prctl.h).
_PR_SET_PDEATHSIG = 1
#: glibc's mallopt parameters (malloc.h) and the values a worker sets: blocks below 32 MB (glibc's largest
#: M_MMAP_THRESHOLD on 64 bits) come from the heap, and freed heap memory stays in the process.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_KEPT_BYTES, _HEAP_BLOCK_BYTES = 2**31 - 1, 32 << 20  # mallopt takes a C int


def single_blas_thread() -> None:
    """For the ``heoslice`` command's own process, before numpy loads: one OpenBLAS thread. heoslice makes no
    BLAS call worth threads (its workers are processes), and OpenBLAS's pools, started when numpy and scipy
    load it, only spin. A value the user set is kept."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def skip_exit_collection() -> None:
    """For the ``heoslice`` command's own process, once its command is done: its objects need no collection
    pass at exit (a long one once slicing has loaded its compiled kernels)."""
    gc.freeze()


def keep_freed_memory() -> bool:
    """Let this process's C allocator keep the memory numpy frees, for the next layer; True if it could.

    Every layer allocates and frees the same few-MB arrays; glibc otherwise maps them afresh or
    gives them back to the kernel, and each comes back as newly zeroed pages (page faults and system
    time: benchmarks/README.md). What is kept is what the worker had used (a heap this large can hold
    fragments). Called in worker processes only (a library caller's own process keeps its settings);
    a no-op where the C library has no mallopt (not glibc).
    """
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    done = [mallopt(_M_MMAP_THRESHOLD, _HEAP_BLOCK_BYTES), mallopt(_M_TRIM_THRESHOLD, _KEPT_BYTES)]
    return all(done)


def die_with_parent(parent: int) -> None:
    """In a child forked by process ``parent``: be killed (SIGKILL) when the parent ends, however it ends;
    end at once if it has ended already (before this call). Where the C library has no prctl (not Linux),
    only the second part is done."""
    prctl = getattr(ctypes.CDLL(None, use_errno=True), "prctl", None)
    if prctl is not None:
        prctl.argtypes, prctl.restype = (ctypes.c_int, ctypes.c_ulong), ctypes.c_int
        prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        os._exit(1)


def _enter_child(parent: int) -> None:
    """First thing in every forked child: ignore the signals that end a run (the parent reports them), then
    take them back from the mask the fork was made under (:func:`_forking`), and die with ``parent``."""
    for number in ENDING_SIGNALS:
        signal.signal(number, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, ENDING_SIGNALS)
    die_with_parent(parent)


def _enter_worker(parent: int) -> None:
    """First thing in a worker: :func:`_enter_child`, and keep freed memory for the next layer."""
    _enter_child(parent)
    keep_freed_memory()


def _start(enter: Callable[[int], None], target: Callable, *args):
    """Fork a daemon process that calls ``enter(pid of this process)`` (:func:`_enter_child` or
    :func:`_enter_worker`) and then ``target(*args)``, with the ending signals held back over the fork: the
    child ignores them before any can arrive (they reach this process after)."""
    child = get_context("fork").Process(target=_child_main, args=(os.getpid(), enter, target, args), daemon=True)
    held = signal.pthread_sigmask(signal.SIG_BLOCK, ENDING_SIGNALS)
    try:
        child.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
    return child


def _child_main(parent: int, enter: Callable[[int], None], target: Callable, args: tuple) -> None:
    """What a child forked by :func:`_start` runs."""
    enter(parent)
    target(*args)


def _end(child) -> None:
    """Kill ``child`` if it still runs, and wait for it: afterwards it writes nothing more."""
    if child.is_alive():
        child.kill()
    child.join()


@contextmanager
def _frozen_for_forks() -> Iterator[Callable[[], None]]:
    """Yields ``freeze()``, to call before each fork: the objects made so far move out of the collector's
    generations, as Python's gc documentation advises, so that its passes do not write to (and copy) the
    pages this process shares with its children. Unfrozen after; a caller's own freezing is left alone."""
    ours = gc.get_freeze_count() == 0
    try:
        yield gc.freeze if ours else (lambda: None)
    finally:
        if ours:
            gc.unfreeze()


@dataclass(frozen=True)
class Ahead:
    """What a helper made ahead: the runs' contours ((start, stop) -> (contours, slice s, chain s)) and some
    runs' solid bits ((start, stop) -> (layers, h, ceil(w / 8)) uint8), read-only views of shared memory."""

    contours: dict = field(default_factory=dict)
    masks: dict = field(default_factory=dict)

    def run_contours(self, context: RunContext, start: int, stop: int) -> SlicedRun:
        """The run's contours as made ahead, or made now."""
        from heoslice.pipeline.runs import run_contours

        made = self.contours.get((start, stop))
        return made if made is not None else run_contours(context, start, stop)

    def slice_run(self, context: RunContext, start: int, stop: int, cache: PipelineCache) -> RunResult:
        """:func:`heoslice.pipeline.runs.slice_run` of a run, with what was made of it ahead."""
        from heoslice.pipeline.runs import slice_run

        return slice_run(context, start, stop, cache, self.contours.get((start, stop)),
                         self.masks.get((start, stop)))


@contextmanager
def _sliced_ahead(context: RunContext, runs: list[tuple[int, int]]) -> Iterator[Callable[[], Ahead]]:
    """Fork a helper that slices and chains ``runs`` in order, then makes their layers' solid bits
    (:func:`_slice_ahead`), while the body runs; yields ``collect()``, which stops it and returns what it
    finished (:class:`Ahead`): views of the memory it shares with this process (and with the workers forked
    after). What a helper that fails or does not answer in _AHEAD_WAIT_S did not finish, the workers make."""
    if not runs:
        yield Ahead
        return
    buffer = mmap.mmap(-1, AHEAD_BYTES)
    ours, theirs = get_context("fork").Pipe()
    helper = _start(_enter_child, _slice_ahead, context, runs, buffer, theirs, ours)
    theirs.close()

    def collect() -> Ahead:
        try:
            ours.send(None)
            if not ours.poll(_AHEAD_WAIT_S):
                return Ahead()
            placed, masks = ours.recv()
        except (OSError, EOFError):
            return Ahead()
        return Ahead(contours={run: (_shared_contours(buffer, layout), *seconds) for run, layout, seconds in placed},
                     masks={run: _shared_array(buffer, where) for run, where in masks})

    try:
        yield collect
    except BaseException:
        ours.close()
        _end(helper)  # an error or an interruption: nothing more is wanted of it
        raise
    ours.close()
    helper.join(timeout=_AHEAD_WAIT_S)
    _end(helper)


def _slice_ahead(context: RunContext, runs: list[tuple[int, int]], buffer: mmap.mmap, conn,
                 parent_end=None) -> None:
    """Helper process: :func:`run_contours` of ``runs`` in order, then the solid bits of their layers run by
    run, each copied into ``buffer``, until the parent asks (anything on ``conn``, or its end closed) or the
    buffer is full; then send where each run's contours and masks lie. ``parent_end``, the parent's end of the
    pipe as forked into this process, is closed first, so that the parent closing its own is seen here."""
    import numpy as np

    from heoslice.layers.contours import Contours
    from heoslice.layers.rasterising import packed_mask
    from heoslice.pipeline.layer_job import layer_jobs
    from heoslice.pipeline.runs import run_contours

    if parent_end is not None:
        parent_end.close()
    placed, masks, used, mask_bytes = [], [], 0, 0
    try:
        for run in runs:
            if conn.poll():
                break
            contours, *seconds = run_contours(context, *run)
            layout = []
            for name in Contours.__dataclass_fields__:
                where, used = _copy_array(getattr(contours, name), buffer, used)
                layout.append((name, where))
            if used > len(buffer):
                break
            placed.append((run, layout, seconds))
        for run, layout, _ in placed:
            if conn.poll():
                break
            jobs = list(layer_jobs(_shared_contours(buffer, layout), context.mesh, context.grid, context.spec,
                                   context.directory, first_layer=run[0]))
            grid = context.grid
            shape = (len(jobs), grid.height, -(-grid.width // 8))
            mask_bytes += int(np.prod(shape))
            where, used = _place(shape, np.uint8, used)
            if used > len(buffer) or mask_bytes > AHEAD_MASK_BYTES:
                break
            bits = _shared_array(buffer, where, writeable=True)
            for layer, job in enumerate(jobs):
                bits[layer] = packed_mask(job.points, job.offsets, grid)
            masks.append((run, where))
    except Exception:  # noqa: BLE001 - what is not made here the workers make, and they report its errors
        pass
    try:
        conn.recv()
        conn.send((placed, masks))
    except (EOFError, OSError):
        pass  # the parent stopped before it asked (an error, Ctrl-C): nothing is wanted


def _place(shape: tuple, dtype, used: int) -> tuple[tuple, int]:
    """Where an array of ``shape`` and ``dtype`` goes in a shared buffer whose first ``used`` bytes are taken,
    64-byte aligned: ((dtype, shape, offset), bytes taken after)."""
    import numpy as np

    dtype = np.dtype(dtype)
    start = -(-used // 64) * 64
    return (dtype.str, tuple(shape), start), start + dtype.itemsize * int(np.prod(shape))


def _copy_array(array: np.ndarray | None, buffer: mmap.mmap, used: int) -> tuple[tuple | None, int]:
    """Copy ``array`` into ``buffer`` after its first ``used`` bytes (:func:`_place`): (where, bytes taken after;
    None and ``used`` for no array). Nothing is copied past the end (the bytes taken then exceed the length)."""
    if array is None:
        return None, used
    where, used = _place(array.shape, array.dtype, used)
    if used <= len(buffer):
        _shared_array(buffer, where, writeable=True)[...] = array
    return where, used


def _shared_array(buffer: mmap.mmap, where: tuple | None, writeable: bool = False) -> np.ndarray | None:
    """A view (read-only unless ``writeable``) of an array placed in ``buffer`` (:func:`_place`)."""
    import numpy as np

    if where is None:
        return None
    dtype, shape, offset = where
    array = np.ndarray(shape, np.dtype(dtype), buffer=buffer, offset=offset)
    array.flags.writeable = writeable
    return array


def _shared_contours(buffer: mmap.mmap, layout: list) -> Contours:
    """The Contours whose arrays :func:`_slice_ahead` placed in ``buffer`` (layout: (field, where) per field)."""
    from heoslice.layers.contours import Contours

    return Contours(**{name: _shared_array(buffer, where) for name, where in layout})


def _serve(conn, context: RunContext, cache: PipelineCache, ahead: Ahead) -> None:
    """A worker: slice the runs (start, stop) that arrive on ``conn`` until None (or the pipe's end), answering
    each with ("done", RunResult) or ("failed", the exception, with the worker's traceback as a note).
    ``cache`` is this worker's copy, by fork, of what the parent's first layer left to the next."""
    while True:
        try:
            run = conn.recv()
        except (EOFError, OSError):
            return
        if run is None:
            return
        try:
            answer = ("done", ahead.slice_run(context, *run, cache))
        except Exception as err:  # noqa: BLE001 - the parent raises it
            err.add_note(f"in a slice worker:\n{traceback.format_exc()}")
            answer = ("failed", err)
        try:
            conn.send(answer)
        except Exception as err:  # noqa: BLE001 - an exception that cannot be pickled
            conn.send(("failed", RuntimeError(f"{type(answer[1]).__name__}: {answer[1]} ({err})")))


def _run_on_workers(context: RunContext, runs: list[tuple[int, int]], workers: int, cache: PipelineCache,
                    ahead: Ahead, on_done: Callable[[RunResult], None]) -> None:
    """Every run through ``workers`` forked :func:`_serve` processes, each given at most _RUNS_IN_FLIGHT runs
    at once (results arrive in any order; memory stays bounded); the workers are ended on the way out,
    whatever happens, before any error goes on."""
    waiting = list(reversed(runs))
    pool = {}
    try:
        for _ in range(min(workers, len(runs))):
            ours, theirs = get_context("fork").Pipe()
            process = _start(_enter_worker, _serve, theirs, context, cache, ahead)
            theirs.close()
            pool[ours] = (process, [])
        for conn, (_, given) in pool.items():
            while waiting and len(given) < _RUNS_IN_FLIGHT:
                given.append(waiting.pop())
                conn.send(given[-1])
        while any(given for _, given in pool.values()):
            busy = {process.sentinel: conn for conn, (process, given) in pool.items() if given}
            for ready in wait_for([*busy.values(), *busy]):
                conn = busy.get(ready, ready)
                process, given = pool[conn]
                status, outcome = _answer(conn, process)
                if status == "failed":
                    raise outcome
                given.pop(0)
                on_done(outcome)
                if waiting:
                    given.append(waiting.pop())
                    conn.send(given[-1])
                break
    finally:
        for conn, (process, _) in pool.items():
            conn.close()
            _end(process)


def _answer(conn, process) -> tuple:
    """A worker's answer on ``conn``; RuntimeError when it ended without one (killed, out of memory)."""
    try:
        if conn.poll():
            return conn.recv()
    except (EOFError, OSError):
        pass
    process.join(timeout=1.0)
    raise RuntimeError(f"a slice worker ended unexpectedly (exit status {process.exitcode})")


def run_all(context: RunContext, workers: int, on_done: Callable[[RunResult], None]) -> None:
    """Every run of planes through :func:`heoslice.pipeline.runs.slice_run`: in this process, or (but for the
    first layer, rendered here) in ``workers`` forked processes (module docstring). ``on_done`` is called with
    each run's result, in any order, in this process."""
    from heoslice.pipeline.layer_job import PipelineCache
    from heoslice.pipeline.runs import plane_runs, slice_run

    runs = plane_runs(context)
    if workers <= 1:
        cache = PipelineCache()
        for start, stop in runs:
            on_done(slice_run(context, start, stop, cache))
        return
    start, stop = runs[0]
    runs = ([(start + 1, stop)] if stop > start + 1 else []) + runs[1:]
    first = PipelineCache()
    with _frozen_for_forks() as freeze:
        freeze()
        with _sliced_ahead(context, runs if context.spec.grade is not None else []) as collect:
            on_done(slice_run(context, start, start + 1, first))
            ahead = collect()
        if runs:
            freeze()
            _run_on_workers(context, runs, workers, first, ahead, on_done)
