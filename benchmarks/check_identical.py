"""Are heoslice's stacks byte-identical to a recorded list? A guard for changes that must not change outputs.

Slices a fixed set of cases (the shipped vase, plain and coloured by ``heoslice color``;
the bench_prusa meshes one-material and graded with droplet masks; the shared SOFA liver
scaled to organ size when ../shared/data is there) with the ``heoslice`` of this Python,
and compares each stack's files, by SHA-256, with ``benchmarks/identical_stacks.json``.
Each case is recorded as its file count and one digest over the sorted (name, sha256)
pairs of every file in the stack, manifest included. Exit status 0 when every case that
ran matches, 1 otherwise.

Examples:
  python benchmarks/check_identical.py                 # check every case (~5 minutes on 2 cores)
  python benchmarks/check_identical.py --cases shipped-vase,holes-graded
  python benchmarks/check_identical.py --record        # write the list anew from this checkout
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import prusa_meshes  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
RECORD = Path(__file__).resolve().with_name("identical_stacks.json")
GRADED_ARGS = ("--grade", "linear", "--to", "0,255,0", "--nozzle", "0.2", "--channels")
#: The SOFA liver is ~6.4 units long; x25 makes it ~160 mm, the size of a real liver.
LIVER_SCALE = "25"


@dataclass(frozen=True)
class Case:
    """One stack to compare: a model (made by ``make`` into a folder) and the ``slice`` options."""

    name: str
    model: str
    options: tuple[str, ...] = ()


def shared_data() -> Path:
    """The third-party meshes: $HEOSLICE_SHARED_DATA, else ../shared/data beside the repo."""
    return Path(os.environ.get("HEOSLICE_SHARED_DATA", REPO.parent / "shared" / "data"))


def cases() -> list[Case]:
    """Every case, in a fixed order."""
    listed = [
        Case("shipped-vase", "vase.ply"),
        Case("shipped-vase-coloured", "vase_linear.ply"),
        Case("shipped-vase-coloured-graded", "vase_linear.ply", GRADED_ARGS),
    ]
    for name in prusa_meshes.FULL:
        listed.append(Case(f"{name}-plain", f"bench_{name}.ply"))
        listed.append(Case(f"{name}-graded", f"bench_{name}.ply", GRADED_ARGS))
    listed.append(Case("liver-plain", "liver", ("--scale", LIVER_SCALE)))
    listed.append(Case("liver-graded", "liver", ("--scale", LIVER_SCALE) + GRADED_ARGS))
    return listed


def heoslice(*args: str) -> None:
    """Run this Python's heoslice command; raise with its stderr when it fails."""
    done = subprocess.run([sys.executable, "-m", "heoslice", "--no-config", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"heoslice {' '.join(args)}: exit {done.returncode}: {done.stderr.strip()}")


def model_path(case: Case, workdir: Path) -> Path | None:
    """The case's model file, made in ``workdir`` on first use; None when its source is absent."""
    if case.model == "liver":
        liver = shared_data() / "anatomy" / "sofa_liver_smooth.ply"
        return liver if liver.is_file() else None
    path = workdir / case.model
    if path.exists():
        return path
    if case.model == "vase.ply":
        shutil.copyfile(REPO / "examples" / "vase.ply", path)
    elif case.model == "vase_linear.ply":
        heoslice("color", str(model_path(Case("", "vase.ply"), workdir)), "--func", "linear", "-o", str(path))
    else:
        prusa_meshes.build(path.stem.removeprefix("bench_"), quick=False).export(path)
    return path


def stack_digest(stack: Path) -> dict:
    """File count and one SHA-256 over the sorted (name, file sha256) pairs of a stack directory."""
    total = hashlib.sha256()
    files = sorted(p for p in stack.rglob("*") if p.is_file())
    for path in files:
        total.update(f"{path.relative_to(stack).as_posix()}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n"
                     .encode())
    return {"files": len(files), "sha256": total.hexdigest()}


def second_slice(model: Path, case: Case, stack: Path, recorded: dict) -> str:
    """What a stack that differs from its record says on a second slice of the same case (a failure either way):
    whether the second matches the record (the first was not reproducible) and the files that differ between the
    two slices, so that a run that fails once names where to look."""
    again = stack.with_name(stack.name + "_again")
    heoslice("slice", str(model), "-o", str(again), "--force", *case.options)
    files = sorted(p.relative_to(stack) for p in stack.rglob("*") if p.is_file())
    changed = [str(name) for name in files if not (again / name).is_file()
               or (stack / name).read_bytes() != (again / name).read_bytes()]
    matches = stack_digest(again) == recorded
    shutil.rmtree(again)
    return (f"a second slice {'matches the record' if matches else 'does not match the record either'}, "
            f"{len(changed)} file(s) differ between the two slices{': ' + ', '.join(changed[:8]) if changed else ''}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="examples:" + __doc__.split("Examples:")[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", default=None, help="comma-separated case names [default: all]")
    parser.add_argument("--record", action="store_true", help=f"write {RECORD.name} instead of checking it")
    args = parser.parse_args(argv)
    chosen = cases()
    if args.cases:
        wanted = set(args.cases.split(","))
        unknown = wanted - {case.name for case in chosen}
        if unknown:
            parser.error(f"unknown cases: {', '.join(sorted(unknown))}")
        chosen = [case for case in chosen if case.name in wanted]
    recorded = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    failures = 0
    with tempfile.TemporaryDirectory(prefix="heoslice-identical-") as tmp:
        workdir = Path(tmp)
        for case in chosen:
            model = model_path(case, workdir)
            if model is None:
                print(f"{case.name:24s} skipped (no {shared_data()})")
                continue
            stack = workdir / f"{case.name}_stack"
            started = time.perf_counter()
            heoslice("slice", str(model), "-o", str(stack), "--force", *case.options)
            digest = stack_digest(stack)
            seconds = time.perf_counter() - started
            if args.record:
                recorded[case.name] = digest
                verdict = "recorded"
            elif case.name not in recorded:
                verdict, failures = "NOT RECORDED", failures + 1
            elif recorded[case.name] == digest:
                verdict = "identical"
            else:
                verdict, failures = f"DIFFERENT (recorded {recorded[case.name]})", failures + 1
                verdict += "; " + second_slice(model, case, stack, recorded[case.name])
            shutil.rmtree(stack)
            print(f"{case.name:24s} {digest['files']:6d} files  {digest['sha256'][:16]}  {seconds:6.1f} s  {verdict}",
                  flush=True)
    if args.record:
        RECORD.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        print(f"wrote {RECORD}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
