"""The field interior (issue 44) against heoslice's own contour interior, on the same coloured mesh.

For each mesh (prusa_meshes: the procedural set and the shared scans liver_scan, lucy, dragon), the mesh is
coloured once, untimed, by ``heoslice color MESH --ref REF --func sine --periods 3`` (a point reference by
default: the field then varies in all three directions), then ``heoslice slice COLOURED --layer 0.1 --dpi 600``
is timed alternately in the field interior (its default) and with ``--interior contour``, ``--repeats`` times
each, every run into a new directory after os.sync(); it prints the median wall time of each and the ratio
field / contour (the issue's bound: at most 1.5).

Examples:
  python benchmarks/bench_field.py                               # liver_scan, 2 repeats
  python benchmarks/bench_field.py --meshes liver_scan,lucy,dragon --repeats 3
  python benchmarks/bench_field.py --quick --meshes organ       # 40 mm meshes, a smoke test
  python benchmarks/bench_field.py --ref surface --range 0 5    # distance to a sphere inside the mesh
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))

import prusa_meshes  # noqa: E402

MODES = {"field": [], "contour": ["--interior", "contour"]}


def heoslice(*args) -> float:
    """Run the heoslice command; its wall time in seconds (the run's error ends the benchmark)."""
    os.sync()
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "heoslice", *map(str, args)], capture_output=True, text=True)
    elapsed = time.perf_counter() - started
    if done.returncode:
        sys.exit(f"heoslice {' '.join(map(str, args))} failed: {done.stderr.strip()}")
    return elapsed


def coloured(name: str, quick: bool, ref: str, folder: Path, r_range: list[str] | None = None) -> Path:
    """The benchmark mesh, written as PLY and coloured (untimed) by a point-referenced sine (or by distance to a
    sphere of a fifth of its size at its centre, ``ref='surface'``)."""
    mesh = prusa_meshes.build(name, quick)
    plain = folder / f"{name}.ply"
    mesh.export(plain)
    extra = ["--ref", ref]
    if ref == "surface":
        inner = trimesh.creation.icosphere(subdivisions=3, radius=float(mesh.extents.min()) / 5)
        inner.apply_translation(mesh.bounds.mean(axis=0))
        inner.export(folder / "inner.ply")
        extra += ["--surface", folder / "inner.ply"]
    if r_range:
        extra += ["--range", *r_range]
    target = folder / f"{name}_sine.ply"
    heoslice("color", plain, *extra, "--func", "sine", "--periods", "3", "-o", target)
    return target


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--meshes", default="liver_scan", help="comma-separated prusa_meshes names")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="the quick set's sizes (scans at 40 mm)")
    parser.add_argument("--ref", default="point", choices=["point", "plane", "axis", "surface"])
    parser.add_argument("--range", nargs=2, default=None, metavar=("R0", "R1"), help="color's --range, mm")
    parser.add_argument("--layer", default="0.1")
    parser.add_argument("--dpi", default="600")
    parser.add_argument("--json", type=Path, default=None, help="write the results here too")
    options = parser.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        for name in options.meshes.split(","):
            model = coloured(name, options.quick, options.ref, work, options.range)
            times: dict[str, list[float]] = {mode: [] for mode in MODES}
            for repeat in range(options.repeats):
                for mode in (MODES if repeat % 2 == 0 else reversed(list(MODES))):
                    stack = work / f"{name}_{mode}_{repeat}"
                    times[mode].append(heoslice("slice", model, "--layer", options.layer, "--dpi", options.dpi,
                                                "-o", stack, *MODES[mode]))
                    shutil.rmtree(stack)
            median = {mode: statistics.median(values) for mode, values in times.items()}
            results[name] = {"seconds": times, "median": median, "ratio": median["field"] / median["contour"]}
            print(f"{name}: field {median['field']:.1f} s, contour {median['contour']:.1f} s "
                  f"(medians of {options.repeats}), field / contour = {results[name]['ratio']:.2f}", flush=True)
    if options.json is not None:
        options.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
