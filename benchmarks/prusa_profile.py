"""Where heoslice's time goes: run ``heoslice slice`` under cProfile with one worker and split it by stage.

A stage is a heoslice module (loading, slicing, contours, rasterising; stack.py split into
TIFF encoding and the rest: writing files and the manifest). Its time is the inclusive time
of the calls *into* that module made by heoslice's own non-stage code (the CLI and the
pipeline), so nothing is counted twice (calls between stages, or from a library back into
a stage's generator, are already inside their caller's time); whatever remains of the
profiled total is process overhead: interpreter start, imports, the CLI and the pipeline's
own bookkeeping.
"""

from __future__ import annotations

import pstats
import subprocess
import sys
import time
from pathlib import Path

STAGE_MODULES = {"loading.py": "load mesh", "slicing.py": "slicing", "contours.py": "contours",
                 "rasterising.py": "raster"}


def _stage(filename: str, function: str) -> str | None:
    """The stage a heoslice function belongs to, or None outside the stage modules (module bodies run at
    import time, so they count as start-up)."""
    path = Path(filename)
    if "heoslice" not in path.parts or function == "<module>":
        return None
    if path.name == "stack.py":
        return "TIFF encode" if function.startswith("encode") else "write files/manifest"
    return STAGE_MODULES.get(path.name)


def profile_slice(heoslice_args: list[str], output: Path) -> tuple[float, Path]:
    """Run ``python -m cProfile -o output -m heoslice slice ...``; return its wall time (s) and the profile path."""
    command = [sys.executable, "-m", "cProfile", "-o", str(output), "-m", "heoslice", *heoslice_args]
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started, output


def summarise(profile: Path, top: int = 12) -> dict:
    """Seconds per stage, plus the top functions by own time and by cumulative time inside heoslice."""
    stats = pstats.Stats(str(profile))
    total = stats.total_tt
    stages: dict[str, float] = {}
    for (filename, _, function), (_, _, _, _, callers) in stats.stats.items():
        stage = _stage(filename, function)
        if stage is None:
            continue
        for (caller_file, _, caller_function), edge in callers.items():
            if "heoslice" in Path(caller_file).parts and _stage(caller_file, caller_function) is None:
                stages[stage] = stages.get(stage, 0.0) + edge[3]
    stages["overhead (start-up, imports, CLI, pipeline)"] = total - sum(stages.values())

    def label(key) -> str:
        filename, line, function = key
        return f"{Path(filename).name}:{line}({function})"

    rows = [(key, value) for key, value in stats.stats.items()]
    own = sorted(rows, key=lambda row: -row[1][2])[:top]
    inside = sorted((row for row in rows if "heoslice" in Path(row[0][0]).parts), key=lambda row: -row[1][3])[:top]
    return {
        "total_s": total,
        "stages_s": dict(sorted(stages.items(), key=lambda item: -item[1])),
        "top_own_s": [{"function": label(key), "calls": value[1], "own_s": value[2], "cumulative_s": value[3]}
                      for key, value in own],
        "top_cumulative_heoslice_s": [{"function": label(key), "calls": value[1], "cumulative_s": value[3]}
                                      for key, value in inside],
    }


def format_summary(summary: dict, wall_s: float, command: str) -> str:
    """The profile summary as text."""
    lines = [f"Profile of heoslice (-j 1, under cProfile; wall {wall_s:.1f} s, profiled {summary['total_s']:.1f} s):",
             f"  {command}", "  stage                                        s      %"]
    for stage, seconds in summary["stages_s"].items():
        lines.append(f"  {stage:<42} {seconds:7.2f} {100 * seconds / summary['total_s']:5.1f}")
    lines.append("  top functions by own time:")
    for row in summary["top_own_s"]:
        lines.append(f"    {row['own_s']:7.2f} s own {row['cumulative_s']:7.2f} s cum {row['calls']:>8} calls  "
                     f"{row['function']}")
    lines.append("  top heoslice functions by cumulative time:")
    for row in summary["top_cumulative_heoslice_s"]:
        lines.append(f"    {row['cumulative_s']:7.2f} s cum {row['calls']:>8} calls  {row['function']}")
    return "\n".join(lines)
