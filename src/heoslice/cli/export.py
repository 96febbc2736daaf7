"""``heoslice export``: a verified stack in another printer's format (GrabCAD Voxel Print, plain PNG)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from heoslice.cli.common import progress_bar
from heoslice.errors import InputError

#: Library parameter names -> the options that set them, for error messages.
FLAGS = {"format": "--format", "pitch_mm": "--pitch", "dpi": "--dpi", "background": "--background"}


def _colour(text: str | None) -> tuple[int, int, int] | None:
    if text is None:
        return None
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0 <= v <= 255 for v in values):
        raise InputError(f"--background: expected R,G,B with integers 0..255, got {text[:40]!r}")
    return values


@click.command("export", epilog="""\b
Examples:
  heoslice export liver_stack --format voxel-print -o liver_voxels
  heoslice export liver_stack --format voxel-print --pitch 0.014 -o liver_voxels.zip
  heoslice export vase_stack --format png -o vase_png.zip
  heoslice export liver_stack --format gcvf -o liver.gcvf      # GrabCAD Print opens it as it is
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("--format", "format_name", required=True, help="Export format: voxel-print, gcvf or png.")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Folder to write, or a .zip file (gcvf: a .gcvf file).")
@click.option("--pitch", type=float, default=None, help="Layer pitch of the export, mm [voxel-print, gcvf: 0.027].")
@click.option("--dpi", default=None, help="Resolution of the export: N or NxM [voxel-print, gcvf: 600x300].")
@click.option("--background", default=None, help="Colour of empty pixels, R,G,B [voxel-print: 0,0,0].")
@click.option("--force", is_flag=True, help="Replace OUTPUT if it exists.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def export(stack: Path, format_name: str, output: Path, pitch: float | None, dpi: str | None, background: str | None,
           force: bool, as_json: bool) -> None:
    """Write STACK in another printer's format to OUTPUT, checking it as verify does while it is read
    (a stack with a problem is refused and nothing is written)."""
    from heoslice.export import ExportOptions, export_stack
    from heoslice.stack import check_input_path

    check_input_path(stack)
    if dpi is not None:  # slice's parser of --dpi; its module loads the slicing stages, so only when asked
        from heoslice.cli.slice import parse_dpi

        dpi = tuple(parse_dpi(dpi))
    options = ExportOptions(pitch_mm=pitch, dpi=dpi, background=_colour(background))
    try:
        with progress_bar(f"exporting {format_name}", enabled=not as_json) as writing:
            summary = export_stack(stack, format_name, output, options, force=force, writing=writing)
    except InputError as err:
        name, _, rest = str(err).partition(": ")
        if name in FLAGS:
            raise InputError(f"{FLAGS[name]}: {rest}") from err
        raise
    if as_json:
        click.echo(json.dumps({"stack": str(stack), "ok": True, **summary}))
    else:
        click.echo(f"{output}: {summary['files']} files ({format_name})")
