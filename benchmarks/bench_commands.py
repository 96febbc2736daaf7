"""Every command that reads a stack, timed against the slice that made the stack (issue 46).

For each benchmark stack (the real scans of prusa_meshes.SCANS, graded with droplet masks as
bench_prusa.py's ``--graded`` slices them, and a multi-part stack: the liver scan with a 30 mm ball
inside it, ``--parts``), at 0.1 mm and 600 dpi: slice it, then run ``verify``, ``preview --section``
(through the middle of the image, across x and across y), ``export --format png``, ``export --format voxel-print``
and ``print --dry-run`` on it, each once per repeat, in that order, the repeats alternating, and read_floor.py (the
reading alone that every command over the whole stack needs: its files read and hashed, every strip inflated). Reports each command's
wall time as a ratio to the slice's of the same repeat (median over repeats), its CPU time and the
peak RSS of its largest process (GNU time, as bench_prusa.py measures) and the load average around the
stack's runs, against the targets of issue
46: verify <= 0.3, preview --section <= 0.1, export png and voxel-print <= 1, print --dry-run <= 0.2.
Outputs go to a temporary folder (``--workdir`` keeps them) and are deleted at the end. With ``--baseline SRC``
(a folder holding an earlier ``heoslice`` package, e.g. ``git archive`` of a commit's ``src``) each command
is also run by that code, right before this code's run of it on the same stack, so that both ratios come
from one run; ``--commands`` picks the commands.

Examples:
  python benchmarks/bench_commands.py --quick                     # the scans at 40 mm: a smoke test
  python benchmarks/bench_commands.py                             # the scans at their set sizes, 1 repeat
  python benchmarks/bench_commands.py --stacks dragon,parts --repeats 2 --json results.json
  git archive main src | tar -x -C /tmp/base && cp src/heoslice/_compiled*.so /tmp/base/src/heoslice/
  python benchmarks/bench_commands.py --stacks parts --baseline /tmp/base/src --commands verify,"export png"
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

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))

import prusa_meshes  # noqa: E402
from bench_prusa import GRADED_ARGS, heoslice_base  # noqa: E402
from prusa_measure import compile_bytecode, run_measured  # noqa: E402

from heoslice import procedural  # noqa: E402

#: Command -> (arguments after the stack, the target ratio to the slice's wall time).
COMMANDS = {
    "verify": ([], 0.3),
    "preview --section": (["preview", "--section"], 0.1),
    "preview --section y": (["preview", "--section"], 0.1),
    "export png": (["export", "--format", "png"], 1.0),
    "export voxel-print": (["export", "--format", "voxel-print"], 1.0),
    "print --dry-run": (["print", "--dry-run"], 0.2),
    "read floor": ([], None),
}
#: The reading every whole-stack command needs and nothing else (read_floor.py): not a heoslice command.
FLOOR = [sys.executable, str(Path(__file__).with_name("read_floor.py"))]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="examples:" + __doc__.split("Examples:")[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="the scans at 40 mm (prusa_meshes' quick set)")
    parser.add_argument("--stacks", default=None,
                        help=f"comma-separated, from {','.join(prusa_meshes.available_scans())},parts [default: all]")
    parser.add_argument("--repeats", type=int, default=1, help="slices and command runs per stack [1]")
    parser.add_argument("--workdir", type=Path, default=None, help="where meshes and outputs go [a temp dir]")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the results as JSON to PATH")
    parser.add_argument("--baseline", type=Path, default=None, metavar="SRC",
                        help="also run each command with the heoslice package in SRC (on PYTHONPATH), alternating")
    parser.add_argument("--commands", default=None,
                        help=f"comma-separated, from {','.join(COMMANDS)} [default: all]")
    return parser.parse_args(argv)


def write_meshes(name: str, quick: bool, folder: Path) -> tuple[list[Path], list[str]]:
    """The mesh files of one benchmark stack and the slice arguments that make it."""
    if name != "parts":
        path = folder / f"{name}.stl"
        prusa_meshes.scan(name, quick).export(path)
        return [path], GRADED_ARGS
    liver = prusa_meshes.scan("liver_scan", quick)
    ball = procedural.sphere((4.0 if quick else 15.0), subdivisions=4)
    ball.apply_translation(liver.centroid - ball.centroid)
    paths = [folder / "liver.stl", folder / "lesion.stl"]
    liver.export(paths[0])
    trimesh.Trimesh(ball.vertices, ball.faces).export(paths[1])
    return paths, ["--parts", "--part", "liver=M1", "--part", "lesion=M2"]


def command_args(name: str, stack: Path, output: Path) -> list[str]:
    """The heoslice arguments of one timed command on ``stack``."""
    if name == "verify":
        return ["verify", str(stack)]
    if name.startswith("preview --section"):
        manifest = json.loads((stack / "manifest.json").read_text())
        image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
        x_left, y_top = image["origin_mm"]
        cut = (f"y={y_top - image['height'] * py / 2:.3f}" if name.endswith(" y")
               else f"x={x_left + image['width'] * px / 2:.3f}")
        return ["preview", str(stack), "--section", cut, "-o", str(output.with_suffix(".png")), "--force"]
    if name == "read floor":
        return [str(stack)]
    args, _ = COMMANDS[name]
    if args[0] == "export":
        return ["export", str(stack), *args[1:], "-o", str(output), "--force"]
    return ["print", str(stack), "--dry-run"]


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    names = args.stacks.split(",") if args.stacks else [*prusa_meshes.available_scans(), "parts"]
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_commands_"))
    work.mkdir(parents=True, exist_ok=True)
    base = heoslice_base()
    commands = args.commands.split(",") if args.commands else list(COMMANDS)
    unknown = sorted(set(commands) - set(COMMANDS))
    if unknown:
        raise SystemExit(f"--commands: unknown {', '.join(unknown)}; choose from {', '.join(COMMANDS)}")
    runners = [("", base, None)]
    compile_bytecode(Path(procedural.__file__).parent)  # heoslice's bytecode, as an install writes it
    if args.baseline is not None:
        compile_bytecode(args.baseline / "heoslice")
        environment = {**os.environ, "PYTHONPATH": str(args.baseline.resolve())}
        runners.insert(0, ("baseline ", [sys.executable, "-m", "heoslice"], environment))
    results = {}
    try:
        for name in names:
            folder = work / name
            folder.mkdir(exist_ok=True)
            meshes, extra = write_meshes(name, args.quick, folder)
            rows: dict[str, list] = {"slice": []}
            load_before = os.getloadavg()[0]
            for repeat in range(args.repeats):
                stack = folder / "stack"
                sliced = run_measured([*base, "slice", *map(str, meshes), "--layer", "0.1", "--dpi", "600", *extra,
                                       "-o", str(stack), "--force"], folder / f"slice{repeat}.log")
                if sliced.returncode:
                    raise SystemExit(f"{name}: slice failed, see {sliced.log}")
                rows["slice"].append((sliced.wall_s, sliced.cpu_s, sliced.max_rss_mb, 1.0))
                for command in commands:
                    for label, runner, environment in runners if command != "read floor" else [("", FLOOR, None)]:
                        output = folder / f"out_{command.replace(' ', '_').replace('-', '')}"
                        done = run_measured([*runner, *command_args(command, stack, output)],
                                            folder / f"{label.strip()}{command.replace(' ', '_')}{repeat}.log",
                                            env=environment)
                        if done.returncode:
                            raise SystemExit(f"{name}: {label}{command} failed, see {done.log}")
                        rows.setdefault(label + command, []).append((done.wall_s, done.cpu_s, done.max_rss_mb,
                                                                     done.wall_s / sliced.wall_s))
                        shutil.rmtree(output, ignore_errors=True)
            manifest = json.loads((folder / "stack" / "manifest.json").read_text())
            image = manifest["image"]
            results[name] = {"layers": len(manifest["layers"]), "image": [image["width"], image["height"]],
                             "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
                             **{command: {"wall_s": statistics.median(r[0] for r in runs),
                                          "cpu_s": statistics.median(r[1] for r in runs),
                                          "max_rss_mb": max(r[2] for r in runs),
                                          "ratio": statistics.median(r[3] for r in runs)}
                                for command, runs in rows.items()}}
            report(name, results[name])
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


def report(name: str, result: dict) -> None:
    """One stack's table: each command's wall, CPU, peak RSS and ratio to the slice, against its target."""
    print(f"\n{name}: {result['layers']} layers of {result['image'][0]} x {result['image'][1]} px "
          f"(1-minute load average {result['load_average'][0]:g} before, {result['load_average'][1]:g} after)")
    print(f"  {'command':<29} {'wall s':>8} {'CPU s':>8} {'RSS MB':>8} {'x slice':>8} {'target':>7}")
    for command, figures in result.items():
        if not isinstance(figures, dict):
            continue
        target = COMMANDS.get(command.removeprefix("baseline "), (None, None))[1]
        verdict = "" if target is None else (" ok" if figures["ratio"] <= target else " OVER")
        print(f"  {command:<29} {figures['wall_s']:8.2f} {figures['cpu_s']:8.2f} {figures['max_rss_mb']:8.0f} "
              f"{figures['ratio']:8.2f} {'' if target is None else f'{target:7.2f}'}{verdict}")
    sys.stdout.flush()


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
