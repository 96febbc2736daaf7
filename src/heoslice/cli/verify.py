"""``heoslice verify``: check a stack before printing it, optionally against the mesh it came from."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from heoslice.cli.common import plural, signed_percent
from heoslice.errors import VerifyError
from heoslice.mesh import Mesh, load_mesh, scaled, volume_check
from heoslice.stack import (
    check_input_path,
    layer_height_problems,
    stack_volume_mm3,
    verify_stack,
)


def mesh_checks(manifest: dict, mesh: Mesh, scale: float, tolerance: float) -> tuple[list[str], list[str], dict]:
    """Compare a stack with its (scaled) mesh: volume (the library's rule) and layers against the z-range.

    Returns (problems, warnings, summary).
    """
    model = mesh.source
    problems: list[str] = []
    warnings = [f"{model}: {text}" for text in mesh.warnings]
    source = manifest.get("source")
    if isinstance(source, dict) and source.get("sha256") not in (None, mesh.sha256):
        warnings.append(f"{model}: not the file this stack was sliced from "
                        f"({source.get('file', '?')}, sha256 differs)")
    volume = volume_check(mesh, stack_volume_mm3(manifest), tolerance)
    problems += [volume.problem] if volume.problem else []
    warnings += [volume.warning] if volume.warning else []
    z_min, z_max = (float(v) for v in mesh.bounds[:, 2])
    problems += layer_height_problems(manifest, z_min, z_max, "the mesh's")
    summary = {"file": str(model), "scale": scale, "watertight": volume.watertight,
               "volume_mm3": volume.mesh_volume_mm3, "relative_volume_difference": volume.relative,
               "z_range_mm": [z_min, z_max]}
    return problems, warnings, summary


@click.command("verify", epilog="""\b
Examples:
  heoslice verify vase_stack/
  heoslice verify vase_stack/ --mesh vase.ply
  heoslice verify scan_stack/ --mesh scan.ply --scale 1000 --json
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("--mesh", "model", type=click.Path(path_type=Path), default=None,
              help="Also compare volume and layer heights with this mesh file.")
@click.option("--scale", type=click.FloatRange(min=0.0, min_open=True), default=1.0, show_default=True,
              help="Scale the mesh was sliced with (as given to 'heoslice slice --scale').")
@click.option("--tolerance", type=click.FloatRange(min=0.0), default=0.01, show_default=True,
              help="Largest relative volume difference accepted with --mesh (0.01 = 1 %).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def verify(stack: Path, model: Path | None, scale: float, tolerance: float, as_json: bool) -> None:
    """Check STACK before printing: manifest (format, version, complete), every layer file
    (inside the stack, present, sha256, size, dpi, solid pixel count), no missing or extra
    layers; with --mesh also the volume and layer heights against the mesh.

    Prints one line per problem. Exit status 0 only when the stack is clean, 4 when it
    has problems, 2 when STACK or the mesh cannot be read at all.
    """
    check_input_path(stack)
    mesh = None
    if model is not None:
        mesh = load_mesh(model)
        mesh = scaled(mesh, scale) if scale != 1.0 else mesh
    report = verify_stack(stack)
    problems, warnings, mesh_summary = list(report.problems), [], None
    if mesh is not None and report.manifest:
        mesh_problems, warnings, mesh_summary = mesh_checks(report.manifest, mesh, scale, tolerance)
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
