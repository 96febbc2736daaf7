"""The slice pipeline's process machinery, all in one place: worker processes, the allocator and collector
settings, BLAS threads, and dying with the parent.

How a slice runs on several cores (:func:`run_all`): the first layer is rendered in this process, so that
what it loads (compiled kernels, codecs) is loaded once and inherited by every fork. Then ``workers``
processes are forked, each handed runs of planes over its own pipe, at most two at a time; they slice, chain,
render and write them and send back what they wrote. Every child ignores the signals that end a run (Ctrl-C,
SIGTERM, SIGHUP: the parent reports them) and is killed by the kernel when the parent ends however it ends
(``PR_SET_PDEATHSIG``), so nothing writes into the stack after the parent has gone.

That fast path needs Linux with glibc (fork, prctl, mallopt). Elsewhere, or with ``HEOSLICE_PORTABLE=1``
(:func:`portable`), the **portable path** is taken, byte for byte the same stack: workers are started by
``spawn`` (a fresh interpreter that is given the run's context, never a fork), each from an empty cache (the
cache only saves work); a worker ignores the same signals and watches its parent from a thread, ending itself
within :data:`_PARENT_POLL_S` of the parent's end; no C library function is called.

Work over the layers of a finished stack (verify, previews, exports, the print's dry run) goes through
:func:`ordered_map`: the same forked, signal-ignoring, parent-bound workers, each handed a few items at a time,
the results yielded in the items' order.

Importing this module loads nothing but the standard library, so that the ``heoslice`` command can set its
process's environment for numpy (:func:`command_environment`) before numpy loads; numpy and the pipeline's
stages are imported by the functions that use them.
"""

from __future__ import annotations

import atexit
import ctypes
import gc
import os
import signal
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing import get_context
from multiprocessing.connection import wait as wait_for
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from heoslice.pipeline.layer_job import PipelineCache
    from heoslice.pipeline.runs import RunContext, RunResult

#: Signals that end a slice: the parent turns them into one line; its children ignore them.
ENDING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Runs handed to one worker at a time: the next is waiting when it finishes one.
_RUNS_IN_FLIGHT = 2
#: ordered_map's batches: at least this many per worker, of at most this many items (:func:`batch_size`); what a
#: message and its answer cost, against an item one by one, is in benchmarks/README.md.
_BATCHES_PER_WORKER, _MOST_BATCHED = 16, 8
#: prctl(2) option: the signal this process gets when its parent ends (linux/prctl.h).
_PR_SET_PDEATHSIG = 1
#: glibc's mallopt parameters (malloc.h) and the values a worker sets: blocks below 32 MB (glibc's largest
#: M_MMAP_THRESHOLD on 64 bits) come from the heap, and freed heap memory stays in the process.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_KEPT_BYTES, _HEAP_BLOCK_BYTES = 2**31 - 1, 32 << 20  # mallopt takes a C int


#: The environment variable that forces the portable path (module docstring) where the fast one would run.
PORTABLE_VARIABLE = "HEOSLICE_PORTABLE"
#: How often a portable worker checks that its parent still runs, s.
_PARENT_POLL_S = 0.2


def portable() -> bool:
    """Whether slices take the portable path: HEOSLICE_PORTABLE set (not empty or 0), or this platform lacks what
    the fast path calls (fork, Linux's prctl, glibc's mallopt)."""
    import multiprocessing
    import platform
    import sys

    if os.environ.get(PORTABLE_VARIABLE, "") not in ("", "0"):
        return True
    return not (sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
                and "fork" in multiprocessing.get_all_start_methods())


def usable_cores() -> int:
    """The cores this process may run on (its affinity, where the platform has one: Linux), at least 1."""
    affinity = getattr(os, "sched_getaffinity", None)
    return max(1, len(affinity(0)) if affinity is not None else os.cpu_count() or 1)


#: What the ``heoslice`` command sets in its own environment before numpy loads, unless the user set it, and why:
#: heoslice makes no BLAS call worth threads (its workers are processes), and OpenBLAS's pools, started when
#: numpy and scipy load it, only spin; numpy's transparent huge pages for large arrays make each fresh
#: array's first touch zero (and, where the kernel defragments for them, compact) 2 MB at a time, which
#: costs a large mesh's load more system time than the faults it saves (benchmarks/README.md).
COMMAND_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "NUMPY_MADVISE_HUGEPAGE": "0"}


def command_environment() -> None:
    """For the ``heoslice`` command's own process, before numpy loads: :data:`COMMAND_ENVIRONMENT`'s values,
    each where the user has not set the variable (the workers it forks inherit what numpy made of them)."""
    for variable, value in COMMAND_ENVIRONMENT.items():
        os.environ.setdefault(variable, value)


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


def _enter_portable_worker(parent: int) -> None:
    """First thing in a spawned worker (the portable path): ignore the signals that end a run, take them back from
    the mask it was started under, and end (at once, or within _PARENT_POLL_S) when ``parent`` has ended: a
    daemon thread watches the parent's id, as no C library call is made."""
    import threading
    import time

    for number in ENDING_SIGNALS:
        signal.signal(number, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, ENDING_SIGNALS)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_PARENT_POLL_S)
        os._exit(1)

    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


#: Every child :func:`_start` started and :func:`_end` has not ended: killed when this process exits
#: (:func:`_end_started`), so that one a signal kept from reaching its pool (Ctrl-C between its start and its
#: caller keeping it) does not outlive a run, nor hang the exit: multiprocessing's own exit handler asks daemon
#: children to end with SIGTERM, which ours ignore, then waits for them.
_STARTED: set = set()


def _start(enter: Callable[[int], None], target: Callable, *args, method: str = "fork"):
    """Start (fork, or ``method``) a daemon process that calls ``enter(pid of this process)`` (:func:`_enter_child`,
    :func:`_enter_worker` or :func:`_enter_portable_worker`) and then ``target(*args)``, with the ending signals
    held back over the start: the child ignores them before any can arrive (they reach this process after), and
    it is in :data:`_STARTED` before any can."""
    child = get_context(method).Process(target=_child_main, args=(os.getpid(), enter, target, args), daemon=True)
    held = signal.pthread_sigmask(signal.SIG_BLOCK, ENDING_SIGNALS)
    try:
        child.start()
        _STARTED.add(child)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
    return child


@atexit.register
def _end_started() -> None:
    """At this process's exit, before multiprocessing's own handler (exit handlers run last registered first, and
    ``multiprocessing.connection``, imported above, registered it with ``multiprocessing.util``): every started
    child not yet ended is killed and reaped."""
    for child in list(_STARTED):
        _end(child)


def _child_main(parent: int, enter: Callable[[int], None], target: Callable, args: tuple) -> None:
    """What a child forked by :func:`_start` runs."""
    enter(parent)
    target(*args)


def _end(child) -> None:
    """Kill ``child`` if it still runs, and wait for it: afterwards it writes nothing more."""
    if child.is_alive():
        child.kill()
    child.join()
    _STARTED.discard(child)


@contextmanager
def _frozen_for_forks() -> Iterator[None]:
    """Around forking the workers: the objects made so far move out of the collector's generations, as
    Python's gc documentation advises, so that its passes do not write to (and copy) the pages this process
    shares with its children. Unfrozen after; a caller's own freezing is left alone."""
    ours = gc.get_freeze_count() == 0
    if ours:
        gc.freeze()
    try:
        yield
    finally:
        if ours:
            gc.unfreeze()


def _serve(conn, context: RunContext, cache: PipelineCache) -> None:
    """A worker: slice the runs (start, stop) that arrive on ``conn`` until None (or the pipe's end), answering
    each with ("done", RunResult) or ("failed", the exception, with the worker's traceback as a note), after
    a ("layers", count) message as each layer is written. ``cache`` is this worker's copy, by fork, of what
    the parent's first layer left to the next."""
    from heoslice.pipeline.runs import slice_run

    while True:
        try:
            run = conn.recv()
        except (EOFError, OSError):
            return
        if run is None:
            return
        try:
            answer = ("done", slice_run(context, *run, cache, lambda count: conn.send(("layers", count))))
        except Exception as err:  # noqa: BLE001 - the parent raises it
            err.add_note(f"in a slice worker:\n{traceback.format_exc()}")
            answer = ("failed", err)
        try:
            conn.send(answer)
        except Exception as err:  # noqa: BLE001 - an exception that cannot be pickled
            conn.send(("failed", RuntimeError(f"{type(answer[1]).__name__}: {answer[1]} ({err})")))


def _run_on_workers(context: RunContext, runs: list[tuple[int, int]], workers: int, cache: PipelineCache,
                    on_done: Callable[[RunResult], None], on_layers: Callable[[int], None] | None = None,
                    spawned: bool = False) -> None:
    """Every run through ``workers`` forked (``spawned``: spawned, the portable path) :func:`_serve` processes,
    each given at most _RUNS_IN_FLIGHT runs at once (results arrive in any order; memory stays bounded); the
    workers' per-layer reports go to ``on_layers``; the workers are ended on the way out, whatever happens,
    before any error goes on."""
    waiting = list(reversed(runs))
    pool = {}
    method, enter = ("spawn", _enter_portable_worker) if spawned else ("fork", _enter_worker)
    try:
        for _ in range(min(workers, len(runs))):
            ours, theirs = get_context(method).Pipe()
            process = _start(enter, _serve, theirs, context, cache, method=method)
            theirs.close()
            pool[ours] = (process, [])
        _fill(pool, waiting, lambda run: run)
        while any(given for _, given in pool.values()):
            conn, status, outcome = _next_answer(pool)
            if status == "layers":
                if on_layers is not None:
                    on_layers(outcome)
                continue
            pool[conn][1].pop(0)
            on_done(outcome)
            _fill(pool, waiting, lambda run: run)
    finally:
        for conn, (process, _) in pool.items():
            conn.close()
            _end(process)


def _fill(pool: dict, waiting: list, payload: Callable) -> None:
    """Give each worker of ``pool`` (conn -> (process, its items given)) items from the end of ``waiting`` until it
    holds _RUNS_IN_FLIGHT; ``payload(item)`` is what is sent for an item."""
    for conn, (process, given) in pool.items():
        while waiting and len(given) < _RUNS_IN_FLIGHT:
            given.append(waiting.pop())
            _give(conn, process, payload(given[-1]))


def _next_answer(pool: dict) -> tuple:
    """Wait for one worker of ``pool`` that holds items to answer: (its conn, status, outcome); a worker's
    failure is raised here, and RuntimeError when one ended without an answer."""
    busy = {process.sentinel: conn for conn, (process, given) in pool.items() if given}
    ready = wait_for([*busy.values(), *busy])[0]
    conn = busy.get(ready, ready)
    status, outcome = _answer(conn, pool[conn][0])
    if status == "failed":
        raise outcome
    return conn, status, outcome


def _give(conn, process, run: tuple[int, int]) -> None:
    """Send a worker its next run; RuntimeError when it has ended (its end of the pipe is closed)."""
    try:
        conn.send(run)
    except OSError:
        raise _ended(process) from None


def _answer(conn, process) -> tuple:
    """A worker's answer on ``conn``; RuntimeError when it ended without one (killed, out of memory)."""
    try:
        if conn.poll():
            return conn.recv()
    except (EOFError, OSError):
        pass
    raise _ended(process)


def _ended(process) -> RuntimeError:
    """The error of a worker that ended without answering (killed, out of memory), once it is reaped."""
    process.join(timeout=1.0)
    return RuntimeError(f"a slice worker ended unexpectedly (exit status {process.exitcode})")


def run_all(context: RunContext, workers: int, on_done: Callable[[RunResult], None],
            on_layers: Callable[[int], None] | None = None) -> None:
    """Every run of planes through :func:`heoslice.pipeline.runs.slice_run`: in this process, or (but for the
    first layer, rendered here) in ``workers`` forked processes, or on the portable path in ``workers`` spawned
    ones (module docstring). ``on_done`` is called with each run's result, in any order, in this process;
    ``on_layers(count)`` (when given) as layers are written, each worker reporting them over its pipe as it
    writes them (for a progress bar)."""
    from heoslice.pipeline.layer_job import PipelineCache
    from heoslice.pipeline.runs import plane_runs, slice_run

    runs = plane_runs(context)
    if workers <= 1:
        cache = PipelineCache()
        for start, stop in runs:
            on_done(slice_run(context, start, stop, cache, on_layers))
        return
    if portable():
        _run_on_workers(context, runs, workers, PipelineCache(), on_done, on_layers, spawned=True)
        return
    start, stop = runs[0]
    runs = ([(start + 1, stop)] if stop > start + 1 else []) + runs[1:]
    first = PipelineCache()
    on_done(slice_run(context, start, start + 1, first, on_layers))
    if runs:
        with _frozen_for_forks():
            _run_on_workers(context, runs, workers, first, on_done, on_layers)


def default_workers() -> int:
    """Worker processes for work over layers when the caller names none: one per core this process may run on."""
    return usable_cores()


def batch_size(count: int, workers: int, most: int = _MOST_BATCHED) -> int:
    """Items of one :func:`ordered_map` batch: at least _BATCHES_PER_WORKER batches per worker (progress shown
    per batch still moves), at most ``most`` items (results in flight stay a few layers' worth)."""
    return max(1, min(most, count // (workers * _BATCHES_PER_WORKER)))


def _serve_items(conn, function: Callable) -> None:
    """A map worker: answer each item that arrives on ``conn`` with ("done", function(item)) or ("failed",
    the exception with the worker's traceback as a note), until None (or the pipe's end)."""
    while True:
        try:
            item = conn.recv()
        except (EOFError, OSError):
            return
        if item is None:
            return
        try:
            answer = ("done", function(item))
        except Exception as err:  # noqa: BLE001 - the parent raises it
            err.add_note(f"in a worker:\n{traceback.format_exc()}")
            answer = ("failed", err)
        try:
            conn.send(answer)
        except Exception as err:  # noqa: BLE001 - an exception or result that cannot be pickled
            conn.send(("failed", RuntimeError(f"{type(answer[1]).__name__}: {answer[1]} ({err})")))


def ordered_map(function: Callable, items, workers: int | None = None,
                most_batched: int = _MOST_BATCHED) -> Iterator:
    """``function(item)`` for every item of ``items``, yielded in the items' order: computed in ``workers``
    forked processes (default :func:`default_workers`), or in this process when there is one worker or one item.
    The items travel in batches of consecutive items (:func:`batch_size`: a message and an answer per batch,
    not per item), each worker given at most _RUNS_IN_FLIGHT batches at once; results that arrive early wait
    for their turn, so memory is bounded by a few batches' results whatever the count. A worker's exception is
    raised here; the workers are ended on the way out, however the caller stops.

    ``function`` reaches the workers by fork (a closure is fine); items and results travel pickled, so keep
    them small (layer numbers in, counts or encoded files out). On the portable path (:func:`portable`: no
    fork) the items are computed in this process, in order. ``most_batched`` caps a batch: higher where tens of
    thousands of tiny items make the round trips, not the work, the cost and their results are small."""
    items = list(items)
    workers = default_workers() if workers is None else workers
    if workers <= 1 or len(items) <= 1 or portable():
        for item in items:
            yield function(item)
        return
    size = batch_size(len(items), workers, most_batched)
    batches = [items[at:at + size] for at in range(0, len(items), size)]
    waiting = list(reversed(list(enumerate(batches))))
    pool: dict = {}
    arrived: dict[int, list] = {}
    turn = 0
    try:
        with _frozen_for_forks():
            for _ in range(min(workers, len(batches))):
                ours, theirs = get_context("fork").Pipe()
                process = _start(_enter_worker, _serve_items, theirs, lambda batch: [function(i) for i in batch])
                theirs.close()
                pool[ours] = (process, [])
        _fill(pool, waiting, lambda numbered: numbered[1])
        while turn < len(batches):
            while turn in arrived:
                yield from arrived.pop(turn)
                turn += 1
            if turn == len(batches):
                break
            conn, _, outcome = _next_answer(pool)
            number, _ = pool[conn][1].pop(0)
            arrived[number] = outcome
            _fill(pool, waiting, lambda numbered: numbered[1])
    finally:
        for conn, (process, _) in pool.items():
            conn.close()
            _end(process)
