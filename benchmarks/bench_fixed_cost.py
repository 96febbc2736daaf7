"""The fixed cost of heoslice's paths: wall time, CPU and peak RSS of slicing a tiny part (a 10 mm cube, two
layers at 50 dpi), one-material against graded with droplet masks, alternating.

Per-layer work is negligible there, so the figures are what every slice of the path pays before its first
layer: the interpreter, numpy and the mesh readers, and for the graded path numba with its compiled kernels
loaded from their cache (its LLVM runtime), the floor under the graded path's peak RSS on any job. A graded
slice runs once untimed first, so numba's on-disk cache is filled.

Examples:
  python benchmarks/bench_fixed_cost.py
  python benchmarks/bench_fixed_cost.py --repeats 9
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_prusa import GRADED_ARGS, heoslice_base  # noqa: E402
from prusa_measure import run_measured, tail  # noqa: E402

from heoslice import procedural  # noqa: E402

#: The path name -> what it adds to ``heoslice slice CUBE``.
PATHS = {"one-material": [], "graded": GRADED_ARGS}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.split("\n\n")[-1:]))
    parser.add_argument("--repeats", type=int, default=5, help="runs of each path, alternating [5]")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_fixed_") as folder:
        work = Path(folder)
        cube = work / "cube.ply"
        procedural.box((10.0, 10.0, 10.0)).export(cube)

        def command(extra: list[str]) -> list[str]:
            return heoslice_base() + ["slice", str(cube), "--layer", "5", "--dpi", "50", "-j", "1", "-o",
                                      str(work / "stack"), "--force", *extra]

        run_measured(command(GRADED_ARGS), work / "warm.log")
        figures: dict[str, list[tuple[float, float, float]]] = {name: [] for name in PATHS}
        for _ in range(args.repeats):
            for name, extra in PATHS.items():
                measured = run_measured(command(extra), work / "run.log")
                if measured.returncode:
                    raise SystemExit(f"{name}: heoslice failed ({measured.returncode}): {tail(measured.log)}")
                figures[name].append((measured.wall_s, measured.cpu_s, measured.max_rss_mb))
    print(f"A 10 mm cube, 2 layers at 50 dpi, -j 1; medians of {args.repeats} alternating runs [min-max]:")
    print(f"{'path':<14}{'wall s':>18}{'cpu s':>18}{'max RSS MB':>22}")
    for name, rows in figures.items():
        columns = np.array(rows)
        cells = [f"{np.median(c):.2f} [{c.min():.2f}-{c.max():.2f}]" for c in columns.T[:2]]
        rss = columns[:, 2]
        cells.append(f"{np.median(rss):.0f} [{rss.min():.0f}-{rss.max():.0f}]")
        print(f"{name:<14}{cells[0]:>18}{cells[1]:>18}{cells[2]:>22}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
