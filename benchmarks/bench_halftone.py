"""Halftoning methods (``slice --halftone``) compared: quality on procedural layers, speed on the benchmark scans.

    python benchmarks/bench_halftone.py                  # quality, then speed on the scans (organ size, 2 mm layers)
    python benchmarks/bench_halftone.py --quick          # quality, then speed on the scans made 40 mm, 0.5 mm layers
    python benchmarks/bench_halftone.py --no-speed       # quality only (a few seconds)
    python benchmarks/bench_halftone.py --quick --no-quality --scans liver_scan --repeats 2

Quality (each method, in this process): over a 1 cm^2 region of constant mix inside a layer, on 3
layers, the largest error of a material's delivered share over the region and over every 1 mm x 1 mm
window (2 mm for ordered), for the mixes 30/70, 50/50, 20/35/45 and 5/95; the power of a constant 30 %
mix below 2 cycles/mm (Hann-windowed periodogram of a 256 x 256 window, layers 1..9 of a run of 10),
as a ratio to ordered's; and over 10 consecutive layers of a constant 30 % (and 70 %) mix the share
of pixels whose material is the same in all 10 (independent layers: 0.3^10 + 0.7^10 = 0.028), the
worst over every window of 10 of the first 1033 layers (ordered, blue noise; error diffusion: of 42
layers, its error carried and started afresh every 8 as a slice's runs of planes do), beside the
ordered dither's before issue 48 (its figure of 0.137).

Speed: ``heoslice slice SCAN --grade linear --to 0,255,0 --nozzle 0.2 --channels --halftone METHOD``
(bench_prusa's graded arguments) on each benchmark scan (prusa_meshes.SCANS, from ../shared/data), the
methods alternating in every round (after one untimed run of each), wall time of the whole command; the
median per method and its ratio to ordered's in the same run; beside it the command's CPU time (user + system,
all its processes), which other work on the machine inflates less than the wall time; the load average last.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import prusa_meshes  # noqa: E402
from test_grading_halftone_methods import (  # noqa: E402
    CENTIMETRE,
    MILLIMETRE,
    TWO_MILLIMETRES,
    columns_of_one_material,
    constant_mix,
    hashed_ordered_tile,
    layers_of,
    low_frequency_power,
    stacked_material,
    window_shares,
)

from heoslice.grading.halftone import METHODS  # noqa: E402

GRADED_ARGS = ["--grade", "linear", "--to", "0,255,0", "--nozzle", "0.2", "--channels"]
MIXES = [(0.3, 0.7), (0.5, 0.5), (0.2, 0.35, 0.45), (0.05, 0.95)]


def share_errors(method: str, shares, margin: int = 20) -> tuple[float, float]:
    """(largest error over the 1 cm^2 region, largest over its 1 mm windows (ordered: 2 mm)) of any material on
    3 layers."""
    mix = np.zeros((CENTIMETRE + 2 * margin, CENTIMETRE + 2 * margin, len(shares)))
    mix[..., 0] = 1.0
    mix[margin:-margin, margin:-margin] = shares
    window = TWO_MILLIMETRES if method == "ordered" else MILLIMETRE
    region_error = window_error = 0.0
    for masks in layers_of(mix, method, 3, first=17):
        region = masks[:, margin:-margin, margin:-margin]
        for material, share in enumerate(shares):
            region_error = max(region_error, abs(region[material].mean() - share))
            window_error = max(window_error, float(np.abs(window_shares(region[material], window) - share).max()))
    return region_error, window_error


def quality() -> None:
    mix = constant_mix((0.3, 0.7), 512, 512)
    print("quality (procedural layers)")
    print(f"  {'method':<16} {'mix':<16} {'1 cm^2 err':>10} {'window err':>10}")
    for method in METHODS:
        for shares in MIXES:
            region, window = share_errors(method, shares)
            print(f"  {method:<16} {'/'.join(f'{100 * s:g}' for s in shares):<16} {100 * region:9.2f}% "
                  f"{100 * window:9.2f}%")
    powers, same = {}, {}
    for method in METHODS:
        stack = layers_of(mix, method, 10)[:, 0, 128:384, 128:384]
        powers[method] = float(np.mean([low_frequency_power(mask) for mask in stack[1:]]))
        same[method] = [float(columns_of_one_material(stacked_material(method, share)).max()) for share in (0.3, 0.7)]
    independent = 0.3 ** 10 + 0.7 ** 10
    print(f"  {'method':<16} {'power < 2/mm':>12} {'/ ordered':>9} {'same in 10 layers, worst (30 %, 70 %)':>38} "
          f"{'/ 0.028':>12}")
    for method in METHODS:
        print(f"  {method:<16} {powers[method]:12.3f} {powers[method] / powers['ordered']:9.3f} "
              f"{same[method][0]:18.4f} {same[method][1]:19.4f} {same[method][0] / independent:5.2f} "
              f"{same[method][1] / independent:5.2f}")
    hashed = columns_of_one_material(np.stack([hashed_ordered_tile(layer) < 0.3 for layer in range(1033)]))
    print(f"  ordered dither before issue 48 (tiles by a hash of the layer): worst {hashed.max():.4f} "
          f"(layers {int(hashed.argmax())}..{int(hashed.argmax()) + 9}), {(hashed > 1.5 * independent).mean():.1%} "
          "of the windows over 1.5x")


def speed(quick: bool, repeats: int, layer_mm: float, wanted: list[str] | None = None,
          methods: list[str] = list(METHODS)) -> None:
    scans = [name for name in prusa_meshes.available_scans() if wanted is None or name in wanted]
    if not scans:
        print("speed: no benchmark scans (../shared/data or $HEOSLICE_SHARED_DATA); skipped")
        return
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        print(f"speed: graded slice ({' '.join(GRADED_ARGS)} --layer {layer_mm:g}), wall s, "
              f"median of {repeats}, methods alternating; load average {os.getloadavg()[0]:.2f}")
        for name in scans:
            model = work / f"{name}.ply"
            prusa_meshes.scan(name, quick).export(model)
            times = {method: [] for method in methods}
            cpu = {method: [] for method in methods}
            for method in methods:  # untimed: kernels compiled or loaded, caches warm
                subprocess.run([sys.executable, "-m", "heoslice", "--no-config", "slice", str(model), "-o",
                                str(work / f"warm_{name}_{method}"), "--layer", str(4 * layer_mm), "--halftone", method,
                                *GRADED_ARGS], check=True, capture_output=True)
            for round_number in range(repeats):
                order = methods if round_number % 2 == 0 else methods[::-1]
                for method in order:
                    out = work / f"{name}_{method}_{round_number}"
                    before, started = children_cpu(), time.perf_counter()
                    subprocess.run([sys.executable, "-m", "heoslice", "--no-config", "slice", str(model), "-o",
                                    str(out), "--layer", str(layer_mm), "--halftone", method, *GRADED_ARGS],
                                   check=True, capture_output=True)
                    times[method].append(time.perf_counter() - started)
                    cpu[method].append(children_cpu() - before)
            base, cpu_base = statistics.median(times["ordered"]), statistics.median(cpu["ordered"])
            line = "  ".join(f"{method} {statistics.median(t):.2f} s ({statistics.median(t) / base:.2f}x; "
                             f"CPU {statistics.median(cpu[method]):.2f} s, "
                             f"{statistics.median(cpu[method]) / cpu_base:.2f}x)" for method, t in times.items())
            print(f"  {name:<11} {line}", flush=True)
        print(f"  load average {' '.join(f'{value:.2f}' for value in os.getloadavg())} on {os.cpu_count()} cores")


def children_cpu() -> float:
    """User + system CPU seconds of this process's finished children (the commands timed): a measure that other
    work on the machine inflates less than wall time."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="scans made 40 mm, 0.5 mm layers")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-speed", action="store_true", help="quality only")
    parser.add_argument("--no-quality", action="store_true", help="speed only")
    parser.add_argument("--scans", default=None, help="comma-separated scans to time [all available]")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods, ordered first")
    args = parser.parse_args()
    if not args.no_quality:
        quality()
    if not args.no_speed:
        speed(args.quick, args.repeats, 0.5 if args.quick else 2.0, args.scans.split(",") if args.scans else None,
              args.methods.split(","))


if __name__ == "__main__":
    main()
