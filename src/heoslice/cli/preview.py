"""``heoslice preview``: a layer of a stack, or a contact sheet of several, as a PNG."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from heoslice.errors import InputError, OutputError
from heoslice.stack import check_input_path, read_manifest


@click.command("preview", epilog="""\b
Examples:
  heoslice preview vase_stack --layer 40 -o layer40.png
  heoslice preview vase_stack --layer 40 --size 800        # at most 800 px wide or high
  heoslice preview liver_stack --sheet --layers 0:100:10 -o sheet.png
  heoslice preview liver_stack --sheet                     # 16 layers spread over the stack
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("--layer", "layer", type=int, default=None, help="Layer number to show [default: the middle layer].")
@click.option("--sheet", is_flag=True, help="A contact sheet of several layers instead of one.")
@click.option("--layers", "layers", default=None,
              help="Layers of the sheet: N, A,B,C or START:STOP[:STEP] [default: 16 spread evenly].")
@click.option("--size", type=click.IntRange(min=16), default=None,
              help="Longest side of a single-layer image, px [default: full resolution].")
@click.option("--tile", type=click.IntRange(min=32), default=256, show_default=True,
              help="Longest side of each sheet tile, px.")
@click.option("--columns", type=click.IntRange(min=1), default=None, help="Sheet columns [default: square].")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="PNG file to write [default: ./STACK_layer_NNNNN.png or ./STACK_sheet.png].")
def preview(stack: Path, layer: int | None, sheet: bool, layers: str | None, size: int | None, tile: int,
            columns: int | None, output: Path | None) -> None:
    """Write a PNG of one layer of STACK (or a contact sheet with --sheet).

    Files are checked against the manifest (inside the stack, sha256, size) before
    they are decoded. Coloured layers are shown over dark grey, layers with droplet masks
    (slice --channels) in their materials' colours over dark grey; other 1-bit layers dark on white.
    """
    from heoslice.preview import contact_sheet, layer_image, parse_layers

    check_input_path(stack)
    manifest = read_manifest(stack)
    count = len(manifest["layers"])
    if count == 0:
        raise InputError(f"{stack}: the stack has no layers")
    name = stack.resolve().name
    if sheet:
        if layer is not None:
            raise InputError("--layer: use --layers with --sheet")
        chosen = parse_layers(layers, count) if layers else sorted(set(np.linspace(0, count - 1, min(16, count))
                                                                       .round().astype(int).tolist()))
        image = contact_sheet(stack, chosen, tile=tile, columns=columns, manifest=manifest)
        target = output or Path.cwd() / f"{name}_sheet.png"
    else:
        if layers is not None:
            raise InputError("--layers: only used with --sheet")
        index = count // 2 if layer is None else layer
        image = layer_image(stack, index, size, manifest)
        target = output or Path.cwd() / f"{name}_layer_{index:05d}.png"
    if target.suffix.lower() != ".png":
        raise InputError(f"{target}: the preview is a PNG; give a file name ending in .png")
    try:
        image.save(target, format="PNG")
    except OSError as err:
        raise OutputError(f"{target}: cannot write ({err.strerror or err})") from err
    click.echo(f"{target}: {image.size[0]} x {image.size[1]} px")

