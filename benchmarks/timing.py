"""Timing helper shared by the benchmark scripts (run as `python benchmarks/bench_*.py`)."""

from __future__ import annotations

import time


def best_of(repeats: int, function, *args, clock=time.perf_counter):
    """(best seconds, last result) of calling ``function(*args)`` ``repeats`` times.

    ``clock`` is wall time by default; pass ``time.process_time`` for CPU seconds.
    """
    best, result = float("inf"), None
    for _ in range(repeats):
        started = clock()
        result = function(*args)
        best = min(best, clock() - started)
    return best, result
