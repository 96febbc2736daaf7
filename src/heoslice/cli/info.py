"""``heoslice info``: what a mesh file or a volume (label map, CT) holds, before slicing it."""

from __future__ import annotations

import json
from pathlib import Path

import click

from heoslice.mesh import load_mesh, mesh_info
from heoslice.volume import is_volume_path


@click.command("info", epilog="""\b
Examples:
  heoslice info vase.ply
  heoslice info liver.stl --json | jq .volume_mm3
  heoslice info example_seg.nii.gz              # a label map: each label's name, voxels and volume
  heoslice info ct_dicom/                       # a DICOM series folder (or a folder of structure files)
""")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--as", "kind", type=click.Choice(["labels", "intensity"]), default=None,
              help="Read a volume as a label map or an intensity volume [default: guessed: whole numbers, none "
                   "negative, at most 1000 values make a label map].")
def info(model: Path, as_json: bool, kind: str | None) -> None:
    """Print MODEL's vertices, triangles, bounding box, watertightness, winding, shells, duplicate faces,
    volume (of the solid the slicer fills: overlapping shells count once, as in 'verify --mesh'), colours.

    For a volume (NIfTI .nii/.nii.gz, NRRD/.seg.nrrd, a folder of one NIfTI per structure, a DICOM series
    folder): its shape, voxel size, orientation, extent in mm and, for a label map, each label's name (where
    the file has one), voxel count and volume.
    """
    if is_volume_path(model):
        from heoslice.volume import load_volume
        from heoslice.volume.info import info_lines, volume_info

        summary = volume_info(load_volume(model, kind))
        if as_json:
            click.echo(json.dumps({"model": str(model), "ok": True, **summary}))
        else:
            click.echo("\n".join(info_lines(summary)))
        return
    summary = mesh_info(load_mesh(model))
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
