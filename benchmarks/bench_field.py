"""The field interior (issue 44) against heoslice's own contour interior and PrusaSlicer's one-material SLA export,
on the same mesh, in one alternating run.

For each mesh (prusa_meshes: the procedural set and the shared scans liver_scan, lucy, dragon), the mesh is
coloured once per reference, untimed, by ``heoslice color MESH --ref REF --func sine --periods 3``: ``point`` (the
bounding-box centre: the field varies in all three directions) and ``surface`` (the distance to an inner sphere of
a fifth of the mesh's smallest extent at its centre, 1,280 triangles: the lab's lesion case; ``--range`` gives its
r range, else 0 .. the largest vertex distance). Then, every repeat in the opposite order to the last, each run
into a new path after os.sync(): ``heoslice slice COLOURED --layer 0.1 --dpi 600`` in the field interior (its
default) and with ``--interior contour`` for each reference, and PrusaSlicer's ``--export-sla`` of the plain mesh
(as bench_prusa.py runs it; left out when it is not installed), heoslice's bytecode written first as an
install writes it (``prusa_measure.compile_bytecode``). It prints the median wall and CPU time of each and
the ratios field / contour (the issue's bound: at most 1.5) and field / PrusaSlicer (at most 0.5). Meshes and
outputs go to a temporary folder, deleted at the end; ``--workdir`` puts that folder elsewhere, e.g. on a file
system without ext4's no-journal inode scan (benchmarks/README.md: it makes each new file cost up to ~0.7 ms of
CPU after many deletions, which a stack of thousands of files pays and PrusaSlicer's one file does not).

Examples:
  python benchmarks/bench_field.py                                  # liver_scan, 2 repeats
  python benchmarks/bench_field.py --meshes liver_scan,lucy,dragon --repeats 2 --json field.json
  python benchmarks/bench_field.py --quick --meshes organ           # 40 mm meshes, a smoke test
  python benchmarks/bench_field.py --refs surface --range 0 5       # the surface case alone, r over 0 .. 5 mm
  python benchmarks/bench_field.py --meshes dragon --workdir /dev/shm  # outputs on tmpfs
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))

import prusa_meshes  # noqa: E402
import prusa_sla  # noqa: E402
from prusa_measure import compile_bytecode, run_measured, tail  # noqa: E402

import heoslice  # noqa: E402

#: What each heoslice mode adds to the slice command.
MODES = {"field": [], "contour": ["--interior", "contour"]}


def heoslice_base() -> list[str]:
    """The installed console script next to this Python, else ``python -m heoslice``."""
    script = Path(sys.executable).with_name("heoslice")
    return [str(script)] if script.exists() else [sys.executable, "-m", "heoslice"]


def coloured(mesh: trimesh.Trimesh, plain: Path, ref: str, folder: Path, r_range: list[str] | None) -> Path:
    """The mesh (written at ``plain``) coloured, untimed, by a sine of 3 periods of the distance to ``ref``: the
    bounding-box centre, or a sphere of a fifth of the smallest extent there (``ref='surface'``, over ``r_range``)."""
    extra = ["--ref", ref]
    if ref == "surface":
        inner = trimesh.creation.icosphere(subdivisions=3, radius=float(mesh.extents.min()) / 5)
        inner.apply_translation(mesh.bounds.mean(axis=0))
        inner.export(folder / "inner.ply")
        extra += ["--surface", str(folder / "inner.ply")] + (["--range", *r_range] if r_range else [])
    target = folder / f"{plain.stem}_{ref}.ply"
    run = run_measured(heoslice_base() + ["color", str(plain), *extra, "--func", "sine", "--periods", "3", "-o",
                                          str(target)], folder / f"color_{ref}.log")
    if run.returncode:
        sys.exit(f"heoslice color failed: {tail(run.log)}")
    return target


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="examples:" + __doc__.split("Examples:")[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", default="liver_scan", help="comma-separated prusa_meshes names [liver_scan]")
    parser.add_argument("--refs", default="point,surface", help="comma-separated references [point,surface]")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="the quick set's sizes (scans at 40 mm)")
    parser.add_argument("--range", nargs=2, default=None, metavar=("R0", "R1"),
                        help="color's --range for the surface reference, mm [0 .. the largest vertex distance]")
    parser.add_argument("--layer", type=float, default=0.1)
    parser.add_argument("--dpi", type=float, default=600.0)
    parser.add_argument("--prusa", default=shutil.which("prusa-slicer"), help="PrusaSlicer [prusa-slicer on PATH]")
    parser.add_argument("--json", type=Path, default=None, help="write the results here too")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="the folder the run's temporary folder goes in [the system's temporary folder]")
    options = parser.parse_args()
    refs = options.refs.split(",")
    if not options.prusa:
        print(prusa_sla.INSTALL_HINT, file=sys.stderr)
    compile_bytecode(Path(heoslice.__file__).parent)
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())}", flush=True)
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench_field_", dir=options.workdir) as work:
        work = Path(work)
        for name in options.meshes.split(","):
            folder = work / name
            folder.mkdir()
            mesh = prusa_meshes.build(name, options.quick)
            plain = folder / f"{name}.stl"
            mesh.export(plain)
            models = {ref: coloured(mesh, plain, ref, folder, options.range) for ref in refs}
            ini = folder / "sla.ini"
            ini.write_text(prusa_sla.sla_ini(prusa_sla.display_for(mesh.extents[:2], options.dpi), options.layer,
                                             float(mesh.extents[2])))
            tools = [(ref, mode) for ref in refs for mode in MODES] + ([("prusa", "one-material")]
                                                                        if options.prusa else [])
            wall: dict[str, list[float]] = {f"{a} {b}": [] for a, b in tools}
            cpu: dict[str, list[float]] = {f"{a} {b}": [] for a, b in tools}
            for repeat in range(options.repeats):
                for ref, mode in (tools if repeat % 2 == 0 else tools[::-1]):
                    key = f"{ref} {mode}"
                    out = folder / f"{ref}_{mode}_{repeat}"
                    if ref == "prusa":
                        command = prusa_sla.prusa_command(options.prusa, ini, out.with_suffix(".sl1"), plain)
                    else:
                        command = heoslice_base() + ["slice", str(models[ref]), "--layer", f"{options.layer:g}",
                                                     "--dpi", f"{options.dpi:g}", "-o", str(out), *MODES[mode]]
                    os.sync()
                    run = run_measured(command, folder / f"{ref}_{mode}_{repeat}.log")
                    if run.returncode:
                        sys.exit(f"{' '.join(command)} failed: {tail(run.log)}")
                    wall[key].append(run.wall_s)
                    cpu[key].append(run.cpu_s)
                    print(f"{name}: {key} run {repeat + 1}: {run.wall_s:.1f} s wall, {run.cpu_s:.1f} s CPU",
                          flush=True)
            median = {key: statistics.median(values) for key, values in wall.items()}
            median_cpu = {key: statistics.median(values) for key, values in cpu.items()}
            ratios = {}
            for ref in refs:
                ratios[f"{ref}: field / contour"] = median[f"{ref} field"] / median[f"{ref} contour"]
                if options.prusa:
                    ratios[f"{ref}: field / PrusaSlicer"] = median[f"{ref} field"] / median["prusa one-material"]
            results[name] = {"wall_s": wall, "cpu_s": cpu, "median_wall_s": median, "median_cpu_s": median_cpu,
                             "ratios_of_median_wall": ratios, "load_average_end": os.getloadavg()}
            for key in median:
                print(f"{name}: {key}: median {median[key]:.1f} s wall, {median_cpu[key]:.1f} s CPU", flush=True)
            for key, value in ratios.items():
                print(f"{name}: {key} = {value:.2f}", flush=True)
            print(f"load average now: {' '.join(f'{v:.2f}' for v in os.getloadavg())}", flush=True)
    if options.json is not None:
        options.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
