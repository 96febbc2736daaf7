"""``heoslice preview``: a layer of a stack, or a contact sheet of several, as a PNG."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from heoslice.cli.common import echo_warnings, progress_bar
from heoslice.cli.options import flags
from heoslice.errors import InputError, VerifyError
from heoslice.files import check_output, write_output
from heoslice.pipeline.parallel import ordered_map
from heoslice.preview.png import is_preview, png_bytes
from heoslice.preview.layer import MAX_PREVIEW_SIDE, MIN_PREVIEW_SIDE
from heoslice.preview.sheet import MAX_SHEET_LAYERS, MAX_TILE, MIN_TILE
from heoslice.stack import check_input_path
from heoslice.stack.verify import check_unread_layers, open_verified, refusal

#: Library parameter names -> the options that set them, for error messages.
FLAGS = {"section": "--section", "size": "--size", "tile": "--tile", "columns": "--columns", "layers": "--layers",
         "layer": "--layer"}


@click.command("preview", epilog="""\b
Examples:
  heoslice preview vase_stack --layer 40 -o layer40.png
  heoslice preview vase_stack --layer 40 --size 800        # at most 800 px wide or high
  heoslice preview liver_stack --sheet --layers 0:100:10 -o sheet.png
  heoslice preview liver_stack --sheet                     # 16 layers spread over the stack
  heoslice preview vase_linear_stack --section x=0 -o section.png
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("--layer", "layer", type=int, default=None, help="Layer number to show [default: the middle layer].")
@click.option("--sheet", is_flag=True, help="A contact sheet of several layers instead of one.")
@click.option("--layers", "layers", default=None,
              help="Layers of the sheet: N, A,B,C or START:STOP[:STEP] [default: 16 spread evenly].")
@click.option("--size", type=click.IntRange(MIN_PREVIEW_SIDE, MAX_PREVIEW_SIDE), default=None,
              help=f"Longest side of a single-layer image, px [default: full resolution, at most {MAX_PREVIEW_SIDE}].")
@click.option("--tile", type=click.IntRange(MIN_TILE, MAX_TILE), default=256, show_default=True,
              help="Longest side of each sheet tile, px.")
@click.option("--columns", type=click.IntRange(1, MAX_SHEET_LAYERS), default=None,
              help="Sheet columns [default: square].")
@click.option("--section", "section", default=None,
              help="A vertical section instead: x=MM or y=MM, in material colours at true aspect ratio.")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="PNG file to write [default: ./STACK_layer_NNNNN.png, ./STACK_sheet.png or "
                   "./STACK_section_x12.5.png].")
@click.option("--force", is_flag=True, help="Replace OUTPUT if it is a preview heoslice wrote.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def preview(stack: Path, layer: int | None, sheet: bool, layers: str | None, size: int | None, tile: int,
            columns: int | None, section: str | None, output: Path | None, force: bool, as_json: bool) -> None:
    """Write a PNG of one layer of STACK (or a contact sheet with --sheet).

    Files are checked against the manifest (inside the stack, sha256, size) before
    they are decoded, and decoded at the size they are drawn. Coloured layers are shown
    over dark grey, layers with droplet masks in their materials'
    colours over dark grey; other 1-bit layers dark on white. Under a layer or a
    section a footer gives its number and z (or the cut's position), a legend of the
    materials in their colours and a scale bar in mm; sheet tiles take the part's aspect.
    """
    check_input_path(stack)
    # verify's own check (every file present, of its layout, mode and sha256): a stack it refuses is not drawn;
    # the layers drawn are checked as they are read (and their pixels where drawn), the others without decoding
    opened = open_verified(stack)
    manifest = opened.manifest
    count = len(manifest["layers"])
    if count == 0:
        raise InputError(f"{stack}: the stack has no layers")
    context = click.get_current_context()
    typed = {name for name in ("size", "tile", "columns")
             if context.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE}
    with flags(FLAGS):
        unused = [name for name in (("size",) if sheet else ("tile", "columns")) if name in typed]
        if unused:
            raise InputError(f"{unused[0]}: " + ("a sheet's tiles are sized by --tile" if sheet
                                                  else "only used with --sheet"))
        target, drawn, draw = _plan(stack, manifest, layer, sheet, layers, size, tile, columns, section, output)
        check_output(target, "preview PNG", force=force, made_here=is_preview, inputs=(stack,))
        if target.suffix.lower() != ".png":
            raise InputError(f"{target}: the preview is a PNG; give a file name ending in .png")
        check_unread_layers(opened, drawn, ordered_map)
        with progress_bar("drawing", enabled=not as_json) as progress:
            try:
                image = draw(progress)
            except VerifyError as err:
                raise refusal(stack, [str(err)]) from err
    write_output(target, png_bytes(image))
    if as_json:
        click.echo(json.dumps({"stack": str(stack), "ok": True, "output": str(target), "width": image.size[0],
                               "height": image.size[1]}))
    else:
        click.echo(f"{target}: {image.size[0]} x {image.size[1]} px")


def _plan(stack: Path, manifest: dict, layer: int | None, sheet: bool, layers: str | None, size: int | None,
          tile: int, columns: int | None, section: str | None, output: Path | None):
    """(target PNG path, the layers it draws, function drawing the PIL image) of the requested preview, options
    checked."""
    from heoslice.preview import (
        annotated_layer_image,
        annotated_section_image,
        contact_sheet,
        parse_layers,
        parse_section,
        sheet_size,
    )
    from heoslice.preview.section import section_grid, section_line
    from heoslice.preview.sheet import layer_aspect

    count = len(manifest["layers"])
    name = stack.resolve().name
    if section is not None:
        if sheet or layer is not None or layers is not None:
            raise InputError("--section: not with --layer, --sheet or --layers")
        axis, position = parse_section(section)
        section_line(manifest, axis, position)
        return (output or Path.cwd() / f"{name}_section_{axis}{position:g}.png",
                np.unique(section_grid(manifest, axis, size)[2]).tolist(),
                lambda progress: annotated_section_image(stack, axis, position, size, manifest, progress))
    if sheet:
        if layer is not None:
            raise InputError("--layer: use --layers with --sheet")
        chosen = parse_layers(layers, count, lambda text: echo_warnings(stack, [text])) if layers else sorted(set(np.linspace(0, count - 1, min(16, count))
                                                                       .round().astype(int).tolist()))
        sheet_size(len(chosen), tile, columns, layer_aspect(manifest))
        return (output or Path.cwd() / f"{name}_sheet.png", chosen,
                lambda progress: contact_sheet(stack, chosen, tile=tile, columns=columns, manifest=manifest,
                                               progress=progress))
    if layers is not None:
        raise InputError("--layers: only used with --sheet")
    index = count // 2 if layer is None else layer
    if not 0 <= index < count:
        raise InputError(f"--layer: layer {index} does not exist (the stack has layers 0..{count - 1})")
    return (output or Path.cwd() / f"{name}_layer_{index:05d}.png", [index],
            lambda progress: annotated_layer_image(stack, index, size, manifest))
