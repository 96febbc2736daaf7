"""heoslice against PrusaSlicer's SLA export on the same meshes, layer height and pixel pitch (issue 6).

For each mesh, runs ``heoslice slice MESH --layer 0.1 --dpi 600 -o DIR --force`` and
``prusa-slicer --export-sla --load sla.ini -o out.sl1 MESH`` alternately, ``--repeats``
times each, and prints the median and min-max wall time, peak memory (largest process,
as /usr/bin/time -v reports it, and the whole process tree), output size and the ratio
heoslice / PrusaSlicer. It then checks that both stacks agree: per-layer solid pixel
counts within 1 % (or 2 pixels, on slivers). ``--profile`` adds a cProfile of heoslice on the organ, split by stage.
``--graded`` also times a graded stack with droplet masks (``GRADED_ARGS`` added to the
same heoslice command) in the same alternation, reports its ratio to PrusaSlicer's
one-material time, and checks that its layers' solid pixels equal the one-material
stack's; ``--coloured`` likewise times a coloured mesh sliced without grading, with
droplet masks (the mesh coloured once, untimed, by ``heoslice color --func linear``, then
sliced with ``COLOURED_ARGS``). The meshes are the procedural ones and, where
../shared/data is present, real scans scaled to organ size (prusa_meshes.SCANS); one untimed
3-layer graded slice runs first (:func:`warm_kernel_cache`). heoslice's modules are compiled to
bytecode first, as an installed package has them. Every run
writes to a new path, and everything written so far is flushed to disk (os.sync) before
it: no run pays for another's writeback, and outputs are deleted only when the benchmark
ends (kept with --workdir). ext4 skips inodes deleted in the last half minute when it
allocates new ones, so a stack's thousands of files created right after deleting
another's cost heoslice up to 2 s of system time on the graded vase (PrusaSlicer writes
one file).

Examples:
  python benchmarks/bench_prusa.py --quick                  # smoke test, < 2 minutes
  python benchmarks/bench_prusa.py                          # the four issue-6 meshes, 2 repeats (~12 min)
  python benchmarks/bench_prusa.py --meshes vase,organ --repeats 5 --json results.json
  python benchmarks/bench_prusa.py --mesh liver.stl --profile
  python benchmarks/bench_prusa.py --meshes vase --graded   # graded + droplet masks vs one-material PrusaSlicer
  python benchmarks/bench_prusa.py --meshes liver_scan,lucy,dragon --graded --coloured   # the real scans

PrusaSlicer is not installed by this script; without it heoslice runs alone.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
import zipfile
from dataclasses import asdict
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))

import prusa_meshes  # noqa: E402
import prusa_profile  # noqa: E402
import prusa_sla  # noqa: E402
from prusa_measure import run_measured, size_on_disk, tail  # noqa: E402

import heoslice  # noqa: E402
from heoslice.stack import read_layer_mask, read_manifest  # noqa: E402

MB = 1024 * 1024
#: What ``--graded`` adds to the heoslice command: the paper's Fig. 3b grading with droplet masks.
GRADED_ARGS = ["--grade", "linear", "--to", "0,255,0", "--nozzle", "0.2", "--channels"]
#: What ``--coloured`` adds when it slices the coloured copy of a mesh: droplet masks, no grading.
COLOURED_ARGS = ["--channels"]


def heoslice_base() -> list[str]:
    """The installed console script next to this Python, else ``python -m heoslice``."""
    script = Path(sys.executable).with_name("heoslice")
    return [str(script)] if script.exists() else [sys.executable, "-m", "heoslice"]


def heoslice_args(model: Path, output: Path, layer: float, dpi: float, jobs: int) -> list[str]:
    """Arguments of ``heoslice`` for one benchmark slice."""
    args = ["slice", str(model), "--layer", f"{layer:g}", "--dpi", f"{dpi:g}", "-o", str(output), "--force"]
    return args + (["-j", str(jobs)] if jobs else [])


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="examples:" + __doc__.split("Examples:")[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small, short meshes and 1 repeat: a smoke test")
    parser.add_argument("--meshes", default=None,
                        help=f"comma-separated meshes from {','.join(prusa_meshes.FULL)} and the scans "
                             f"{','.join(prusa_meshes.SCANS)} [default: all that can be built here, "
                             "or none when --mesh is given]")
    parser.add_argument("--mesh", action="append", type=Path, default=[], metavar="PATH",
                        help="a mesh file to benchmark too (repeatable); non-STL files are converted to binary STL")
    parser.add_argument("--repeats", type=int, default=None, help="runs per tool and mesh [default: 2, quick: 1]")
    parser.add_argument("--layer", type=float, default=0.1, help="layer height, mm [0.1]")
    parser.add_argument("--dpi", type=float, default=600.0, help="resolution, dots per inch [600]")
    parser.add_argument("-j", "--jobs", type=int, default=0, help="heoslice worker processes [0 = its default]")
    parser.add_argument("--prusa", default=None, help="PrusaSlicer executable [default: prusa-slicer on PATH]")
    parser.add_argument("--check-stride", type=int, default=1,
                        help="compare every N-th layer's pixel counts (decoding PNGs is slow) [1]")
    parser.add_argument("--profile", action="store_true",
                        help="also profile heoslice (-j 1, cProfile) on the organ mesh (or the last mesh)")
    parser.add_argument("--graded", action="store_true",
                        help=f"also time heoslice with {' '.join(GRADED_ARGS)} (ratio to PrusaSlicer's one-material time)")
    parser.add_argument("--coloured", action="store_true",
                        help="also time heoslice on a coloured copy of each mesh (color --func linear), sliced with "
                             f"{' '.join(COLOURED_ARGS)}")
    parser.add_argument("--workdir", type=Path, default=None, help="where meshes and outputs go [a temp dir]")
    parser.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH",
                        help="also write all results as JSON to PATH ('-' or no value: stdout, instead of the table)")
    args = parser.parse_args(argv)
    if args.repeats is None:
        args.repeats = 1 if args.quick else 2
    if args.repeats < 1 or args.check_stride < 1:
        parser.error("--repeats and --check-stride must be at least 1")
    known = prusa_meshes.names(args.quick)
    names = args.meshes.split(",") if args.meshes else ([] if args.mesh else known)
    unknown = [name for name in names if name not in known]
    if unknown:
        parser.error(f"--meshes: unknown or unavailable mesh(es) {', '.join(unknown)}; choose from {', '.join(known)}")
    missing = [str(path) for path in args.mesh if not path.is_file()]
    if missing:
        parser.error(f"--mesh: no such file: {', '.join(missing)}")
    args.names = names
    return args


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def prepare_meshes(args: argparse.Namespace, workdir: Path) -> list[tuple[str, Path, trimesh.Trimesh, Path]]:
    """(name, binary STL path, mesh, output folder) for every procedural mesh and mesh file asked for."""
    prepared = []
    for name in args.names:
        started = time.perf_counter()
        mesh = prusa_meshes.build(name, args.quick)
        path = workdir / name / f"{name}.stl"
        path.parent.mkdir(parents=True, exist_ok=True)
        mesh.export(path)
        log(f"{name}: {len(mesh.faces)} triangles, {' x '.join(f'{e:.1f}' for e in mesh.extents)} mm "
            f"(made in {time.perf_counter() - started:.1f} s)")
        prepared.append((name, path, mesh, path.parent))
    for source in args.mesh:
        try:
            mesh = trimesh.load(source, force="mesh")
        except Exception as err:
            raise SystemExit(f"--mesh: cannot read {source}: {' '.join(str(err).split())[:200]}") from None
        name = source.stem
        folder = workdir / f"file-{len(prepared)}-{name}"
        folder.mkdir(parents=True, exist_ok=True)
        path = source if source.suffix.lower() == ".stl" else folder / f"{name}.stl"
        if path != source:
            mesh.export(path)
        log(f"{name}: {len(mesh.faces)} triangles, {' x '.join(f'{e:.1f}' for e in mesh.extents)} mm ({path})")
        prepared.append((name, path, mesh, folder))
    return prepared


def clear(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()


def summarise_runs(runs: list) -> dict:
    """Median, min and max wall time and the peak memories over the runs; {} when a run failed."""
    if not runs or any(run.returncode != 0 for run in runs):
        return {}
    walls = [run.wall_s for run in runs]
    trees = [run.tree_pss_mb for run in runs if run.tree_pss_mb is not None]
    return {"median_s": statistics.median(walls), "min_s": min(walls), "max_s": max(walls),
            "cpu_median_s": statistics.median(run.cpu_s for run in runs),
            "max_rss_mb": max(run.max_rss_mb for run in runs), "tree_pss_mb": max(trees) if trees else None}


def spot_check(stack: Path, manifest: dict) -> list[dict]:
    """Decode three heoslice layers (first, middle, largest) and compare with the manifest's counts."""
    solid = [entry["solid_pixels"] for entry in manifest["layers"]]
    picks = sorted({0, len(solid) // 2, int(np.argmax(solid))})
    return [{"layer": i, "manifest": solid[i], "decoded": int(np.count_nonzero(read_layer_mask(stack, manifest, i)))}
            for i in picks]


def agreement(stack: Path, sl1: Path, stride: int) -> dict:
    """Compare heoslice's per-layer solid pixels (manifest, spot-checked by decoding) with the .sl1's PNGs."""
    manifest = read_manifest(stack)
    with zipfile.ZipFile(sl1) as archive:
        total = sum(1 for name in archive.namelist() if name.lower().endswith(".png"))
        config = archive.read("config.ini").decode(errors="replace") if "config.ini" in archive.namelist() else ""
    index, solid, grey = prusa_sla.sl1_layer_counts(sl1, stride)
    result = prusa_sla.compare_counts(manifest, index, solid, grey, total, spot_checks=spot_check(stack, manifest))
    version = next((line.split("=", 1)[1].strip() for line in config.splitlines()
                    if line.startswith("prusaSlicerVersion")), None)
    return {**result.as_dict(), "prusa_version": version, "stride": stride}


def bench_mesh(name: str, model: Path, mesh: trimesh.Trimesh, folder: Path, args: argparse.Namespace,
               prusa: str | None) -> dict:
    """Alternate heoslice and PrusaSlicer runs on one mesh in ``folder``; summarise and compare their outputs."""
    ini = folder / "sla.ini"
    display = prusa_sla.display_for(mesh.extents[:2], args.dpi)
    ini.write_text(prusa_sla.sla_ini(display, args.layer, float(mesh.extents[2])))
    tools = (["heoslice"] + (["graded"] if args.graded else []) + (["coloured"] if args.coloured else [])
             + (["prusa"] if prusa else []))
    coloured_model = folder / f"{model.stem}_linear.ply"
    if args.coloured:
        run_measured(heoslice_base() + ["color", str(model), "--func", "linear", "-o", str(coloured_model)],
                     folder / "color.log")

    def output(tool: str, repeat: int) -> Path:
        """Where one run writes: a new path per tool and repeat (see the module docstring)."""
        return folder / (f"prusa-{repeat}.sl1" if tool == "prusa" else f"{tool}_stack-{repeat}")

    def command(tool: str, repeat: int) -> list[str]:
        if tool == "prusa":
            return prusa_sla.prusa_command(prusa, ini, output(tool, repeat), model)
        extra = {"graded": GRADED_ARGS, "coloured": COLOURED_ARGS}.get(tool, [])
        source = coloured_model if tool == "coloured" else model
        return heoslice_base() + heoslice_args(source, output(tool, repeat), args.layer, args.dpi, args.jobs) + extra

    runs: dict[str, list] = {tool: [] for tool in tools}
    failed: dict[str, str] = {}
    for repeat in range(args.repeats):
        for tool in tools:
            if tool in failed:
                continue
            os.sync()
            run = run_measured(command(tool, repeat), folder / f"{tool}-{repeat}.log")
            runs[tool].append(run)
            log(f"{name}: {tool} run {repeat + 1}/{args.repeats}: {run.wall_s:.1f} s, "
                f"max RSS {run.max_rss_mb:.0f} MB, tree PSS {fmt(run.tree_pss_mb, '.0f')} MB"
                + ("" if run.returncode == 0 else f"  FAILED (exit {run.returncode})"))
            if run.returncode != 0:
                failed[tool] = f"exit {run.returncode}: {tail(run.log)}"
    last = {tool: output(tool, len(runs[tool]) - 1) for tool in tools}
    stack, sl1 = last["heoslice"], last.get("prusa")
    result = {
        "mesh": name, "file": str(model), "triangles": int(len(mesh.faces)),
        "extents_mm": [round(float(e), 3) for e in mesh.extents],
        "commands": {tool: " ".join(command(tool, 0)) for tool in tools},
        "sla_ini": ini.read_text(),
        "runs": {tool: [{**asdict(run), "log": str(run.log)} for run in tool_runs] for tool, tool_runs in runs.items()},
        "summary": {tool: summarise_runs(tool_runs) for tool, tool_runs in runs.items()},
        "failed": failed,
    }
    if "heoslice" not in failed:
        manifest = read_manifest(stack)
        result["heoslice_image"] = [manifest["image"]["width"], manifest["image"]["height"]]
        result["heoslice_layers"] = len(manifest["layers"])
        result["size_bytes"] = {"heoslice": size_on_disk(stack)}
    for tool in ("graded", "coloured"):
        if tool in tools and tool not in failed and "heoslice" not in failed:
            multi = [entry["solid_pixels"] for entry in read_manifest(last[tool])["layers"]]
            plain = [entry["solid_pixels"] for entry in read_manifest(stack)["layers"]]
            result[f"{tool}_same_solid"] = plain == multi
            result.setdefault("size_bytes", {})[tool] = size_on_disk(last[tool])
    if prusa and "prusa" not in failed:
        result["prusa_image"] = [display.pixels_x, display.pixels_y]
        result.setdefault("size_bytes", {})["prusa"] = size_on_disk(sl1)
        if "heoslice" not in failed:
            started = time.perf_counter()
            result["agreement"] = agreement(stack, sl1, args.check_stride)
            log(f"{name}: compared pixel counts in {time.perf_counter() - started:.1f} s")
    return result


def ratio(a: float | None, b: float | None) -> float | None:
    return a / b if a is not None and b else None


def fmt(value, spec: str = ".2f", missing: str = "-") -> str:
    return missing if value is None else format(value, spec)


def pair(h, p, spec: str) -> str:
    """'h/p' with missing values as '-'."""
    return f"{fmt(h, spec)}/{fmt(p, spec)}"


def timing(s: dict) -> str:
    return f"{s['median_s']:.1f} [{s['min_s']:.1f}-{s['max_s']:.1f}]" if s else "-"


def table(results: list[dict]) -> str:
    """The timing, memory and size table, and the agreement table."""
    w = max([9] + [len(r["mesh"]) + 1 for r in results])
    lines = ["", "Speed, memory, size (wall s median [min-max]; ratio = heoslice / PrusaSlicer; "
             "RSS = largest process, tree = PSS of all processes):",
             f"{'mesh':<{w}}{'tris':>9} {'layers h/p':>10}  {'heoslice s':>18}  {'prusa s':>18}  {'ratio':>5}  "
             f"{'RSS MB h/p':>10} {'ratio':>5}  {'tree MB h/p':>11} {'ratio':>5}  {'size MB h/p':>12} {'ratio':>5}"]
    for r in results:
        h, p = r["summary"].get("heoslice", {}), r["summary"].get("prusa", {})
        size = {tool: value / MB for tool, value in r.get("size_bytes", {}).items()}
        layers = f"{r.get('heoslice_layers', '-')}/{r.get('agreement', {}).get('layers_prusa', '-')}"
        lines.append(
            f"{r['mesh']:<{w}}{r['triangles']:>9} {layers:>10}  {timing(h):>18}  {timing(p):>18}  "
            f"{fmt(ratio(h.get('median_s'), p.get('median_s'))):>5}  "
            f"{pair(h.get('max_rss_mb'), p.get('max_rss_mb'), '.0f'):>10} "
            f"{fmt(ratio(h.get('max_rss_mb'), p.get('max_rss_mb'))):>5}  "
            f"{pair(h.get('tree_pss_mb'), p.get('tree_pss_mb'), '.0f'):>11} "
            f"{fmt(ratio(h.get('tree_pss_mb'), p.get('tree_pss_mb'))):>5}  "
            f"{pair(size.get('heoslice'), size.get('prusa'), '.1f'):>12} "
            f"{fmt(ratio(size.get('heoslice'), size.get('prusa'))):>5}")
    for tool, title in (("graded", f"Graded with droplet masks (heoslice ... {' '.join(GRADED_ARGS)})"),
                        ("coloured", f"Coloured, not graded (color --func linear, then slice ... "
                                     f"{' '.join(COLOURED_ARGS)})")):
        multi = [r for r in results if tool in r["summary"]]
        if not multi:
            continue
        lines += ["", f"{title} against PrusaSlicer's one-material stack (cpu = user + system s, medians):",
                  f"{'mesh':<{w}}{tool + ' s':>18}  {'prusa s':>18}  {'ratio':>5}  {'cpu s m/p':>11} {'ratio':>5}  "
                  f"{'RSS MB m/p':>10} {'ratio':>5}  {'size MB m/p':>12} {'ratio':>5}  solid pixels = one-material's"]
        for r in multi:
            g, p = r["summary"][tool], r["summary"].get("prusa", {})
            size = {name: value / MB for name, value in r.get("size_bytes", {}).items()}
            lines.append(f"{r['mesh']:<{w}}{timing(g):>18}  {timing(p):>18}  "
                         f"{fmt(ratio(g.get('median_s'), p.get('median_s'))):>5}  "
                         f"{pair(g.get('cpu_median_s'), p.get('cpu_median_s'), '.1f'):>11} "
                         f"{fmt(ratio(g.get('cpu_median_s'), p.get('cpu_median_s'))):>5}  "
                         f"{pair(g.get('max_rss_mb'), p.get('max_rss_mb'), '.0f'):>10} "
                         f"{fmt(ratio(g.get('max_rss_mb'), p.get('max_rss_mb'))):>5}  "
                         f"{pair(size.get(tool), size.get('prusa'), '.1f'):>12} "
                         f"{fmt(ratio(size.get(tool), size.get('prusa'))):>5}  "
                         f"{ {True: 'yes', False: 'NO'}.get(r.get(f'{tool}_same_solid'), '-')}")
    agreeing = [r for r in results if "agreement" in r]
    if agreeing:
        lines += ["", "Agreement (solid pixels per layer, matched by height; rel = |h - p| / max(h, p)):",
                  f"{'mesh':<{w}}{'image px h / p':>22}  {'compared':>8}  {'<=1%':>6}  {'median rel':>10}  "
                  f"{'total h-p':>9}  {'h>p/h<p':>11}  {'grey px':>7}  worst layers (z mm: h vs p)"]
        for r in agreeing:
            a = r["agreement"]
            images = f"{'x'.join(map(str, r['heoslice_image']))} / {'x'.join(map(str, r['prusa_image']))}"
            worst = "; ".join(f"{w['z_mm']:g}: {w['heoslice']} vs {w['prusa']} ({100 * w['relative']:.2f}%)"
                              for w in a["worst"][:3])
            lines.append(f"{r['mesh']:<{w}}{images:>22}  {a['compared']:>8}  {a['within']:>6}  "
                         f"{100 * a['median_difference']:>9.3f}%  {100 * a['total_difference']:>+8.3f}%  "
                         f"{a['heoslice_larger']:>5}/{a['prusa_larger']:<5}  {a['grey_pixels']:>7}  {worst}")
            extra = []
            partial = [entry for entry in a["only_heoslice"] if entry["partial_top"]]
            other = [entry for entry in a["only_heoslice"] if not entry["partial_top"]]
            if partial:
                extra.append(f"heoslice's partial top layer ({partial[0]['solid_pixels']} px) has no PrusaSlicer layer "
                             "(it keeps only layers ending at or below the top)")
            if other:
                extra.append(f"layers only in heoslice: {other[:5]}")
            if a["only_prusa"]:
                extra.append(f"layers only in PrusaSlicer: {a['only_prusa'][:5]}")
            bad_spots = [s for s in a["spot_checks"] if s["manifest"] != s["decoded"]]
            extra.append("heoslice manifest counts match decoded TIFFs"
                         if not bad_spots else f"heoslice manifest vs decoded TIFF MISMATCH: {bad_spots}")
            extra.append("AGREE (every compared layer within 1 % or 2 px)" if a["ok"]
                         else "DISAGREE (see worst layers)")
            lines.append(" " * w + "; ".join(extra))
    for r in results:
        for tool, message in r["failed"].items():
            lines.append(f"{r['mesh']}: {tool} failed: {message}")
    return "\n".join(lines)


def compile_bytecode() -> None:
    """Compile heoslice's modules to bytecode once (compileall, as pip does when it installs a package), so that
    no timed run compiles them: an editable install run with PYTHONDONTWRITEBYTECODE set (as in the sandbox
    where this was written) would compile every module in every run, ~0.1 s of the parent's startup."""
    import compileall

    compileall.compile_dir(Path(heoslice.__file__).parent, quiet=1)


def warm_kernel_cache(model: Path, height: float, output: Path) -> None:
    """One untimed graded slice of three layers of ``model`` (``height`` mm tall) before the timed runs: with
    the kernels compiled at install it only warms the file cache; where they run just in time (no compiled
    build, or HEOSLICE_JIT=1) it fills numba's on-disk cache, whose first filling after installing or
    changing heoslice is a one-off per process, not the steady state compared."""
    log("an untimed 3-layer graded slice first (warms the caches)")
    args = heoslice_args(model, output, max(height / 3, 0.1), 50.0, 1) + GRADED_ARGS
    run_measured(heoslice_base() + args, output.with_suffix(".log"))
    clear(output)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    prusa = args.prusa or shutil.which("prusa-slicer")
    if prusa and not (shutil.which(prusa) or Path(prusa).is_file()):
        log(f"--prusa: {prusa} is not an executable file")
        return 2
    if not prusa:
        log(prusa_sla.INSTALL_HINT)
    owned_tmp = None
    if args.workdir is None:
        owned_tmp = tempfile.TemporaryDirectory(prefix="bench_prusa_")
        args.workdir_path = Path(owned_tmp.name)
    else:
        args.workdir.mkdir(parents=True, exist_ok=True)
        args.workdir_path = args.workdir
    started = time.perf_counter()
    load_start = os.getloadavg()
    results, profile = [], None
    try:
        prepared = prepare_meshes(args, args.workdir_path)
        compile_bytecode()
        if args.graded and prepared:
            _, model, mesh, _ = prepared[0]
            warm_kernel_cache(model, float(mesh.extents[2]), args.workdir_path / "warm_stack")
        for name, model, mesh, folder in prepared:
            results.append(bench_mesh(name, model, mesh, folder, args, prusa))
        if args.profile and prepared:
            name, model, _, _ = next((p for p in prepared if p[0] == "organ"), prepared[-1])
            profile_args = heoslice_args(model, args.workdir_path / "profile_stack", args.layer, args.dpi, 1)
            log(f"{name}: profiling heoslice -j 1")
            wall, path = prusa_profile.profile_slice(profile_args, args.workdir_path / "heoslice.prof")
            summary = prusa_profile.summarise(path)
            command = f"python -m cProfile -o heoslice.prof -m heoslice {' '.join(profile_args)}"
            profile = {"mesh": name, "wall_s": wall, "command": command, **summary}
    finally:
        if owned_tmp is not None:
            owned_tmp.cleanup()
    report = {
        "argv": sys.argv, "heoslice_version": heoslice.__version__, "prusa": prusa,
        "cores": len(os.sched_getaffinity(0)), "loadavg_start": load_start, "loadavg_end": os.getloadavg(),
        "total_s": time.perf_counter() - started, "quick": args.quick, "repeats": args.repeats,
        "layer_mm": args.layer, "dpi": args.dpi, "meshes": results, "profile": profile,
    }
    if args.json not in (None, "-"):
        Path(args.json).write_text(json.dumps(report, indent=1))
    if args.json == "-":
        print(json.dumps(report, indent=1))
    else:
        print(table(results))
        if profile:
            print()
            print(prusa_profile.format_summary(profile, profile["wall_s"], profile["command"]))
        print(f"\n{report['cores']} cores, load average {load_start[0]:.2f} at start, "
              f"{report['loadavg_end'][0]:.2f} at end; whole run {report['total_s']:.0f} s. "
              "Figures on a shared machine are noisy: compare ratios from one run.")
    everything_ok = all(not r["failed"] and r.get("agreement", {"ok": True})["ok"]
                        and r.get("graded_same_solid", True) and r.get("coloured_same_solid", True) for r in results)
    return 0 if everything_ok else 1


if __name__ == "__main__":
    sys.exit(main())
