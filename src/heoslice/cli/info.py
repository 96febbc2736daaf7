"""``heoslice info``: what a mesh file or a volume (label map, CT) holds, before slicing it."""

from __future__ import annotations

import json
from pathlib import Path

import click

from heoslice.cli.options import apply_scale, scale_option
from heoslice.errors import InputError
from heoslice.mesh import load_mesh, mesh_info
from heoslice.volume import is_volume_path


#: Shells listed one a line in the text output (--json lists every shell).
SHELLS_SHOWN = 20


def refuse_stack_as_model(path: Path) -> None:
    """InputError (one line) when a folder given as a model or volume is a heoslice stack (its manifest.json):
    read as a volume it would be taken for a DICOM series, and fail on its first layer file."""
    from heoslice.stack.manifest import MANIFEST

    if Path(path).is_dir() and (Path(path) / MANIFEST).is_file():
        raise InputError(f"{path}: is a heoslice stack (it holds {MANIFEST}), not a model or volume: see it with "
                         f"heoslice verify or heoslice preview")


def _shell_lines(shells: list[dict]) -> list[str]:
    """One line per shell (its number, triangles, enclosed volume, bounding box), the first SHELLS_SHOWN."""
    lines = []
    for shell in shells[:SHELLS_SHOWN]:
        (x0, y0, z0), (x1, y1, z1) = shell["bounds_mm"]
        volume = "" if shell["volume_mm3"] is None else f", {shell['volume_mm3']:.6g} mm^3"
        lines.append(f"  shell {shell['number']}:{' ' * max(1, 10 - len(str(shell['number'])))}"
                     f"{shell['triangles']} triangles{volume}, x {x0:.4g} .. {x1:.4g}, y {y0:.4g} .. {y1:.4g}, "
                     f"z {z0:.4g} .. {z1:.4g}")
    if len(shells) > SHELLS_SHOWN:
        lines.append(f"  ... and {len(shells) - SHELLS_SHOWN} more shells (--json lists every one)")
    return lines


@click.command("info", epilog="""\b
Examples:
  heoslice info vase.ply
  heoslice info liver.stl --json | jq .volume_mm3
  heoslice info scan.ply --scale 1000   # a model in metres: bounding box and volume in mm, as sliced
  heoslice info example_seg.nii.gz              # a label map: each label's name, voxels and volume
  heoslice info ct_dicom/                       # a DICOM series folder (or a folder of structure files)
""")
@click.argument("model", type=click.Path(path_type=Path))
@scale_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--as", "kind", type=click.Choice(["labels", "intensity"]), default=None,
              help="Read a volume as a label map or an intensity volume [default: guessed: whole numbers, none "
                   "negative, at most 1000 values make a label map].")
def info(model: Path, scale: float, as_json: bool, kind: str | None) -> None:
    """Print MODEL's vertices, triangles, bounding box, watertightness, winding, shells (each with its number as
    [shells] and --shell-colors use it, its triangles, enclosed volume and bounding box), duplicate faces,
    volume (of the solid the slicer fills: overlapping shells count once, as in 'verify --mesh'), colours;
    with --scale, of the model as 'slice --scale' slices it. A flat mesh (zero height) is described with a
    warning; slice refuses it.

    For a volume (NIfTI .nii/.nii.gz, NRRD/.seg.nrrd, a folder of one NIfTI per structure, a DICOM series
    folder): its shape, voxel size, orientation, extent in mm and, for a label map, each label's name (where
    the file has one), voxel count and volume.
    """
    refuse_stack_as_model(model)
    if is_volume_path(model):
        from heoslice.volume import load_volume
        from heoslice.volume.info import info_lines, volume_info

        if scale != 1.0:
            raise InputError("--scale: a volume is placed by its own voxel size and affine; leave --scale out")
        summary = volume_info(load_volume(model, kind))
        if as_json:
            click.echo(json.dumps({"model": str(model), "ok": True, **summary}))
        else:
            click.echo("\n".join(info_lines(summary)))
        return
    summary = mesh_info(apply_scale(load_mesh(model, flat_ok=True), scale))
    if as_json:
        click.echo(json.dumps({"model": str(model), "ok": True, **summary}))
        return
    low, high = summary["bounds_mm"]
    volume = "n/a (not watertight)" if summary["volume_mm3"] is None else (
        f"{summary['volume_mm3']:.6g} mm^3" + ("" if summary["volume_exact"] else
                                           " (not exact: overlapping shells not united)"))
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
        f"shells:             {summary['shells']} (numbered from 0, as [shells] and --shell-colors use them)",
        *_shell_lines(summary["shell_list"]),
        f"duplicate faces:    {summary['duplicate_faces']} (dropped before slicing)",
        f"volume:             {volume}",
        f"colours:            {colours}"
        f"{', material fraction' if summary['material_fraction'] else ''}",
    ]
    lines += [f"warning:            {text}" for text in summary["warnings"]]
    click.echo("\n".join(lines))
