"""``heoslice verify``: check a stack before printing it, optionally against the mesh it came from."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from heoslice.cli.common import plural, progress_bar, signed_percent
from heoslice.errors import InputError, VerifyError
from heoslice.pipeline.parallel import ordered_map
from heoslice.stack import (
    check_input_path,
    layer_height_problems,
    read_manifest,
    stack_volume_mm3,
    verify_stack,
)

if TYPE_CHECKING:  # the mesh stage loads only with --mesh: a plain verify starts quicker
    from heoslice.mesh import Mesh


def part_files(manifest: dict) -> list[tuple[str, str]]:
    """The files a multi-part stack's parts came from, each once, in the manifest's part order: (file name,
    sha256) pairs; [] for a stack without parts. A 3MF's objects are one file."""
    parts = manifest.get("parts")
    if not isinstance(parts, list):
        return []
    return list(dict.fromkeys((str(part.get("file")), str(part.get("sha256"))) for part in parts
                              if isinstance(part, dict)))


def check_mesh_count(stack: Path, manifest: dict, models: tuple[Path, ...]) -> None:
    """One --mesh per file the stack's parts came from, or one for a stack of one file; InputError (one line)
    otherwise, naming the files the stack needs in their order."""
    files = part_files(manifest)
    if len(models) == max(1, len(files)):
        return
    if len(files) > 1:
        raise InputError(f"--mesh: {stack} was sliced from the {len(files)} part files "
                         f"{', '.join(name for name, _ in files)}: give one --mesh for each, in that order "
                         f"(got {len(models)})")
    raise InputError(f"--mesh: {stack} was sliced from one mesh file: give one --mesh (got {len(models)})")


def source_warnings(manifest: dict, mesh: Mesh, models: tuple[Path, ...]) -> list[str]:
    """A warning per mesh file that is not the one the stack was sliced from (its sha256 differs): each part
    file's against its --mesh with several, else the stack's source against the one mesh."""
    if len(models) > 1:
        given = {Path(part.source): part.sha256 for part in mesh.parts}
        return [f"{model}: not the file of the stack's parts from {name} (sha256 differs)"
                for model, (name, digest) in zip(models, part_files(manifest)) if given.get(Path(model)) != digest]
    source = manifest.get("source")
    if isinstance(source, dict) and source.get("sha256") not in (None, mesh.sha256):
        return [f"{mesh.source}: not the file this stack was sliced from "
                f"({source.get('file', '?')}, sha256 differs)"]
    return []


def mesh_checks(manifest: dict, mesh: Mesh, scale: float, tolerance: float,
                models: tuple[Path, ...] = ()) -> tuple[list[str], list[str], dict]:
    """Compare a stack with its (scaled) mesh (of the --mesh files ``models``): which files they are, volume
    (the library's rule) and layers against the z-range.

    Returns (problems, warnings, summary).
    """
    model = mesh.source
    problems: list[str] = []
    warnings = [f"{model}: {text}" for text in mesh.warnings] + source_warnings(manifest, mesh, models)
    from heoslice.mesh import volume_check

    volume = volume_check(mesh, stack_volume_mm3(manifest), tolerance)
    problems += [volume.problem] if volume.problem else []
    warnings += [volume.warning] if volume.warning else []
    z_min, z_max = (float(v) for v in mesh.bounds[:, 2])
    problems += layer_height_problems(manifest, z_min, z_max, "the mesh's")
    summary = {"file": str(model), "scale": scale, "watertight": volume.watertight,
               "volume_mm3": volume.mesh_volume_mm3, "relative_volume_difference": volume.relative,
               "z_range_mm": [z_min, z_max]}
    return problems, warnings, summary


def _check_count_first(stack: Path, models: tuple[Path, ...]) -> None:
    """:func:`check_mesh_count` before any mesh is loaded or layer hashed (a wrong count is known from the
    manifest alone); a manifest that cannot be read is left to verify_stack's problem lines."""
    try:
        manifest = read_manifest(stack)
    except VerifyError:
        return
    check_mesh_count(stack, manifest, models)


@click.command("verify", epilog="""\b
Examples:
  heoslice verify vase_stack/
  heoslice verify vase_stack/ --mesh vase.ply
  heoslice verify scan_stack/ --mesh scan.ply --scale 1000 --json
  heoslice verify liver_stack/ --mesh liver.stl --mesh lesion.stl   # a multi-part stack: one per part file
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("--mesh", "models", type=click.Path(path_type=Path), multiple=True,
              help="Also compare volume and layer heights with this mesh file; for a multi-part stack (slice "
                   "--parts) repeat it, one per part file in the order they were sliced.")
@click.option("--scale", type=click.FloatRange(min=0.0, min_open=True), default=1.0, show_default=True,
              help="Scale the mesh was sliced with (as given to 'heoslice slice --scale').")
@click.option("--tolerance", type=click.FloatRange(min=0.0), default=0.01, show_default=True,
              help="Largest relative volume difference accepted with --mesh (0.01 = 1 %).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def verify(stack: Path, models: tuple[Path, ...], scale: float, tolerance: float, as_json: bool) -> None:
    """Check STACK before printing: manifest (format, version, complete), every layer file
    (inside the stack, present, sha256, size, dpi, solid pixel count), no missing or extra
    layers; with --mesh also the volume and layer heights against the mesh (the parts' meshes
    together, one --mesh per part file, for a multi-part stack).

    Prints one line per problem. Exit status 0 only when the stack is clean, 4 when it
    has problems, 2 when STACK or the mesh cannot be read at all.
    """
    check_input_path(stack)
    mesh = None
    if models:
        _check_count_first(stack, models)
        from heoslice.mesh import load_assembly, load_mesh, scaled

        mesh = load_mesh(models[0]) if len(models) == 1 else load_assembly(models)
        mesh = scaled(mesh, scale) if scale != 1.0 else mesh
    with progress_bar("verifying", enabled=not as_json) as progress:
        report = verify_stack(stack, progress=progress, layer_map=ordered_map)
    problems, warnings, mesh_summary = list(report.problems), [], None
    if mesh is not None and report.manifest:
        mesh_problems, warnings, mesh_summary = mesh_checks(report.manifest, mesh, scale, tolerance, models)
        problems += mesh_problems
    layers = report.manifest.get("layers", []) if report.manifest else []
    summary = {
        "stack": str(stack),
        "ok": not problems,
        "problems": problems,
        "warnings": warnings,
        "layers": len(layers),
        "volume_mm3": stack_volume_mm3(report.manifest) if report.manifest else None,
        "mesh": mesh_summary,
    }
    if as_json:
        click.echo(json.dumps(summary))
    else:
        for text in warnings:
            click.echo(f"warning: {text}", err=True)
        for line in problems:
            click.echo(line if line.startswith(str(stack)) else f"{stack}: {line}")
        if not problems:
            click.echo(f"{stack}: OK, {plural(len(layers), 'layer')}, volume {summary['volume_mm3']:.6g} mm^3"
                       + (f", mesh volume {mesh_summary['volume_mm3']:.6g} mm^3 "
                          f"({signed_percent(mesh_summary['relative_volume_difference'])})"
                          if mesh_summary and mesh_summary["relative_volume_difference"] is not None else ""))
    sys.stdout.flush()
    if problems:
        raise VerifyError(f"{stack}: {len(problems)} problem(s); do not print this stack")
