"""Contact sheets: several layers of a stack side by side, each labelled with its number and height."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.preview.layer import layer_image
from heoslice.stack import read_manifest


def parse_layers(text: str, count: int) -> list[int]:
    """Layer numbers from 'N', 'A,B,C' or a Python-style range 'START:STOP[:STEP]' (stop excluded, may be empty).

    Raises InputError naming the text when it does not parse or names no existing layer.
    """
    layers: list[int] = []
    try:
        for part in str(text).split(","):
            part = part.strip()
            if ":" in part:
                pieces = [p.strip() for p in part.split(":")]
                if len(pieces) > 3:
                    raise ValueError
                start = int(pieces[0]) if pieces[0] else 0
                stop = int(pieces[1]) if len(pieces) > 1 and pieces[1] else count
                step = int(pieces[2]) if len(pieces) > 2 and pieces[2] else 1
                if step <= 0:
                    raise ValueError
                layers.extend(range(start, min(stop, count), step))
            else:
                layers.append(int(part))
    except ValueError:
        raise InputError(f"--layers: expected N, A,B,C or START:STOP[:STEP], got {text!r}") from None
    bad = [layer for layer in layers if not 0 <= layer < count]
    if bad:
        raise InputError(f"--layers: layer {bad[0]} does not exist (the stack has layers 0..{count - 1})")
    if not layers:
        raise InputError(f"--layers: {text!r} selects no layer (the stack has layers 0..{count - 1})")
    return layers


def contact_sheet(directory: Path, layers: list[int], tile: int = 256, columns: int | None = None,
                  manifest: dict | None = None):
    """PIL RGB image: the given layers side by side, each reduced to ``tile`` pixels and labelled with its number and z."""
    from PIL import Image, ImageDraw

    directory = Path(directory)
    manifest = read_manifest(directory) if manifest is None else manifest
    columns = columns or int(np.ceil(np.sqrt(len(layers))))
    rows = -(-len(layers) // columns)
    label = 14
    sheet = Image.new("RGB", (columns * (tile + 4) + 4, rows * (tile + label + 4) + 4), (200, 200, 200))
    draw = ImageDraw.Draw(sheet)
    for position, index in enumerate(layers):
        image = layer_image(directory, index, tile, manifest)
        x = 4 + (position % columns) * (tile + 4)
        y = 4 + (position // columns) * (tile + label + 4)
        sheet.paste(image, (x + (tile - image.size[0]) // 2, y + label + (tile - image.size[1]) // 2))
        z = manifest["layers"][index]["z_mm"]
        draw.text((x + 2, y + 1), f"layer {index}  z {z:.2f} mm", fill=(0, 0, 0))
    return sheet
