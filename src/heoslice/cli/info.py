"""``heoslice info``: what a mesh file holds, before slicing it."""

from __future__ import annotations

import json
from pathlib import Path

import click

from heoslice.cli.options import apply_scale, scale_option
from heoslice.mesh import load_mesh, mesh_info


@click.command("info", epilog="""\b
Examples:
  heoslice info vase.ply
  heoslice info liver.stl --json | jq .volume_mm3
  heoslice info scan.ply --scale 1000   # a model in metres: bounding box and volume in mm, as sliced
""")
@click.argument("model", type=click.Path(path_type=Path))
@scale_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def info(model: Path, scale: float, as_json: bool) -> None:
    """Print MODEL's vertices, triangles, bounding box, watertightness, winding, shells, duplicate faces,
    volume (of the solid the slicer fills: overlapping shells count once, as in 'verify --mesh'), colours;
    with --scale, of the model as 'slice --scale' slices it."""
    summary = mesh_info(apply_scale(load_mesh(model), scale))
    if as_json:
        click.echo(json.dumps({"model": str(model), "ok": True, **summary}))
        return
    low, high = summary["bounds_mm"]
    volume = "n/a (not watertight)" if summary["volume_mm3"] is None else (
        f"{summary['volume_mm3']:.6g} mm^3" + ("" if summary["volume_exact"] else " (shells not united)"))
    colours = {"vertex": "per-vertex RGB", "face": "per-face RGB (spread to the vertices)"}.get(
        summary["color_source"], "RGB") if summary["colors"] else "none"
    lines = [
        f"file:               {summary['file']}",
        f"vertices:           {summary['vertices']}",
        f"triangles:          {summary['triangles']}",
        f"bounding box (mm):  x {low[0]:.4g} .. {high[0]:.4g}, y {low[1]:.4g} .. {high[1]:.4g}, "
        f"z {low[2]:.4g} .. {high[2]:.4g}",
        f"watertight:         {'yes' if summary['watertight'] else 'no'} "
        f"({summary['boundary_edges']} boundary, {summary['non_manifold_edges']} non-manifold edges)",
        f"winding consistent: {'yes' if summary['winding_consistent'] else 'no'}",
        f"shells:             {summary['shells']}",
        f"duplicate faces:    {summary['duplicate_faces']} (dropped before slicing)",
        f"volume:             {volume}",
        f"colours:            {colours}"
        f"{', material fraction' if summary['material_fraction'] else ''}",
    ]
    lines += [f"warning:            {text}" for text in summary["warnings"]]
    click.echo("\n".join(lines))
