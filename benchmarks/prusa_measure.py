"""Run one command and measure it: wall time, peak RSS of its largest process, peak memory of its process tree.

Peak RSS is "Maximum resident set size" from ``/usr/bin/time -v`` (GNU time), or, without
it, the same rusage from a tiny Python launcher that forks the command and ``wait4``s it.
The command must not be started straight from this (large) Python process: Linux carries
the RSS high-water mark of the pre-exec process over exec into the child's rusage
(``setmax_mm_hiwater_rss``), so every child would report at least the benchmark's own
size. Because heoslice renders layers in worker processes, the memory of the whole tree
matters too: a background thread sums the proportional set size (PSS: shared pages split
between sharers, so forked workers are not double counted) of every process in the tree
from /proc every ``interval`` seconds and keeps the maximum. Sampling can miss spikes
shorter than the interval, and a run that ends before the first sample reports None (not 0), as
off Linux. The interval is half a second:
reading smaps_rollup of heoslice's three processes takes ~14 ms (graded vase), so
sampling every 0.1 s took ~7 % of a 2-core machine from the tree being measured (a
single-process tool paid about a third of that).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Measured:
    """One measured run: wall and CPU time (s, user + system of the process and the children it waited for),
    exit code, peak RSS of the largest process and peak tree PSS (MB)."""

    wall_s: float
    cpu_s: float
    returncode: int
    max_rss_mb: float
    tree_pss_mb: float | None
    log: Path


def _children_by_parent() -> dict[int, list[int]]:
    """Map parent pid -> child pids, from /proc/*/stat."""
    tree: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat", "rb") as handle:
                stat = handle.read()
        except OSError:
            continue
        fields = stat[stat.rfind(b")") + 2:].split()
        tree.setdefault(int(fields[1]), []).append(int(entry.name))
    return tree


def _descendants(pid: int) -> list[int]:
    """pid and every process below it."""
    tree = _children_by_parent()
    found, todo = [], [pid]
    while todo:
        current = todo.pop()
        found.append(current)
        todo.extend(tree.get(current, []))
    return found


def _pss_kb(pid: int) -> int:
    """Proportional set size of one process, kB (0 if it has gone)."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as handle:
            for line in handle:
                if line.startswith("Pss:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


GNU_TIME = "/usr/bin/time"

LAUNCHER = """import os, sys
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as out:
    out.write(f"Maximum resident set size (kbytes): {usage.ru_maxrss}\\n")
    out.write(f"User time (seconds): {usage.ru_utime}\\nSystem time (seconds): {usage.ru_stime}\\n")
sys.exit(os.waitstatus_to_exitcode(status) % 256)
"""


def launcher(report: Path) -> list[str]:
    """The prefix that runs a command from a small process and writes its rusage to ``report``."""
    if shutil.which(GNU_TIME) and Path(GNU_TIME).is_file():
        return [GNU_TIME, "-v", "-o", str(report)]
    return [sys.executable, "-I", "-S", "-c", LAUNCHER, str(report)]


def max_rss_kb(report: Path) -> float:
    """The "Maximum resident set size (kbytes)" line of a GNU time -v (or launcher) report, NaN if absent."""
    text = report.read_text(errors="replace") if report.exists() else ""
    found = re.search(r"Maximum resident set size \(kbytes\): (\d+)", text)
    return float(found.group(1)) if found else float("nan")


def cpu_seconds(report: Path) -> float:
    """User + system seconds of a GNU time -v (or launcher) report, NaN if absent."""
    text = report.read_text(errors="replace") if report.exists() else ""
    times = [float(found) for found in re.findall(r"(?:User|System) time \(seconds\): ([0-9.]+)", text)]
    return sum(times) if len(times) == 2 else float("nan")


def tree_sampling_available() -> bool:
    """True when /proc offers smaps_rollup (Linux >= 4.14)."""
    return Path(f"/proc/{os.getpid()}/smaps_rollup").exists()


def run_measured(command: list[str], log: Path, *, interval: float = 0.5, env: dict | None = None) -> Measured:
    """Run ``command`` with stdout and stderr to ``log``; return its wall time and memory peaks."""
    sample = tree_sampling_available()
    peak_kb, samples = 0, 0
    stop = threading.Event()
    report = log.with_suffix(".rusage")
    with open(log, "wb") as out:
        started = time.perf_counter()
        process = subprocess.Popen(launcher(report) + list(command), stdout=out, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, env=env)

        def sampler() -> None:
            nonlocal peak_kb, samples
            while not stop.wait(interval):
                tree_kb = sum(_pss_kb(pid) for pid in _descendants(process.pid))
                if tree_kb:  # 0: the tree had ended before this sample
                    peak_kb, samples = max(peak_kb, tree_kb), samples + 1

        thread = threading.Thread(target=sampler, daemon=True)
        if sample:
            thread.start()
        process.wait()
        wall = time.perf_counter() - started
        stop.set()
        if sample:
            thread.join()
    return Measured(wall_s=wall, cpu_s=cpu_seconds(report), returncode=process.returncode, max_rss_mb=max_rss_kb(report) / 1024.0,
                    tree_pss_mb=peak_kb / 1024.0 if sample and samples else None, log=log)


def compile_bytecode(package: Path) -> None:
    """Write the bytecode of every module under ``package`` (a folder), as pip does when it installs a package, so
    that a timed command does not compile the sources at every start where no bytecode is written (an editable
    install with PYTHONDONTWRITEBYTECODE set, as on this machine: 0.13 s a heoslice command, benchmarks/README.md)."""
    import compileall

    compileall.compile_dir(str(package), quiet=1)


def tail(path: Path, lines: int = 5) -> str:
    """The last few lines of a log file, for error messages."""
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def size_on_disk(path: Path) -> int:
    """Bytes in a file, or in all files below a directory."""
    path = Path(path)
    if path.is_file():
        return path.stat().st_size
    return sum(entry.stat().st_size for entry in path.rglob("*") if entry.is_file())
