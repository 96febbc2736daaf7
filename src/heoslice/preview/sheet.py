"""Contact sheets: several layers of a stack side by side, each labelled with its number and height."""

from __future__ import annotations

from collections.abc import Callable
from itertools import islice
from pathlib import Path

import numpy as np

from heoslice.errors import InputError, shown
from heoslice.pipeline.parallel import ordered_map
from heoslice.preview.layer import layer_image
from heoslice.stack import read_manifest

#: Most layers one sheet shows, the range of its tile side (px) and its largest size (pixels, ~100 MB RGB).
MAX_SHEET_LAYERS = 400
MIN_TILE, MAX_TILE = 32, 1024
MAX_SHEET_PIXELS = 1 << 25
LABEL_HEIGHT = 14


def parse_layers(text: str, count: int, warn: Callable[[str], None] | None = None) -> list[int]:
    """Layer numbers from 'N', 'A,B,C' or a Python-style range 'START:STOP[:STEP]' (stop excluded, may be empty).

    A range's stop past the last layer is clipped to it, and ``warn`` (if given) is told so in one line.
    Raises InputError naming the text when it does not parse or names no existing layer.
    """
    layers: list[int] = []
    clipped = False
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
                clipped = clipped or stop > count
                layers.extend(islice(range(start, min(stop, count), step), MAX_SHEET_LAYERS + 1 - len(layers)))
            else:
                layers.append(int(part))
            if len(layers) > MAX_SHEET_LAYERS:
                break
    except ValueError:
        raise InputError(f"--layers: expected N, A,B,C or START:STOP[:STEP], got {text[:60]!r}") from None
    if len(layers) > MAX_SHEET_LAYERS:
        raise InputError(f"--layers: {text[:40]!r} selects more than the {MAX_SHEET_LAYERS} layers a sheet shows")
    bad = [layer for layer in layers if not 0 <= layer < count]
    if bad:
        raise InputError(f"--layers: layer {bad[0]} does not exist (the stack has layers 0..{count - 1})")
    if not layers:
        raise InputError(f"--layers: {text[:60]!r} selects no layer (the stack has layers 0..{count - 1})")
    if clipped and warn is not None:
        warn(f"--layers {text[:60]!r} reaches past the last layer: clipped to layers {min(layers)}..{max(layers)} "
             f"(the stack has layers 0..{count - 1})")
    return layers


def tile_box(tile: int, aspect: float) -> tuple[int, int]:
    """(width, height) px of a sheet tile for layers of ``aspect`` (width / height): the longer side ``tile``,
    the other in proportion, so a wide or tall part fills its tiles instead of leaving them grey."""
    if aspect >= 1.0:
        return tile, max(1, min(tile, round(tile / aspect)))
    return max(1, min(tile, round(tile * aspect))), tile


def sheet_size(count: int, tile: int, columns: int | None, aspect: float = 1.0) -> tuple[int, int, int]:
    """(columns, width px, height px) of a sheet of ``count`` tiles of layers of ``aspect`` (width / height;
    :func:`tile_box`), after range-checking ``tile``, ``columns`` and the sheet's pixels (InputError naming the
    parameter). Without ``columns`` the tiles are laid about as many across as up, in proportion to their
    aspect (a square part: ceil(sqrt(count)) columns)."""
    if not (isinstance(tile, int) and MIN_TILE <= tile <= MAX_TILE):
        raise InputError(f"tile: must be an integer from {MIN_TILE} to {MAX_TILE} px, not {shown(tile)}"[:160])
    if not 1 <= count <= MAX_SHEET_LAYERS:
        raise InputError(f"layers: a sheet shows 1 to {MAX_SHEET_LAYERS} layers, not {count}")
    box_width, box_height = tile_box(tile, aspect)
    step_x, step_y = box_width + 4, box_height + LABEL_HEIGHT + 4
    columns = columns or max(1, min(count, int(np.ceil(np.sqrt(count * box_height / box_width) - 1e-9))))
    if not (isinstance(columns, int) and 1 <= columns <= MAX_SHEET_LAYERS):
        raise InputError(f"columns: must be an integer from 1 to {MAX_SHEET_LAYERS}, not {shown(columns)}"[:160])
    columns = min(columns, count)  # no empty columns: more than the tiles lay them all on one row
    rows = -(-count // columns)
    width, height = columns * step_x + 4, rows * step_y + 4
    if width * height > MAX_SHEET_PIXELS:
        raise InputError(f"tile: a sheet of {count} layers in {columns} columns at {tile} px would be "
                         f"{width} x {height} px, more than {MAX_SHEET_PIXELS} pixels; use a smaller --tile")
    return columns, width, height


def layer_aspect(manifest: dict) -> float:
    """Width / height of a stack's layers, mm."""
    image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
    return image["width"] * px / (image["height"] * py)


def contact_sheet(directory: Path, layers: list[int], tile: int = 256, columns: int | None = None,
                  manifest: dict | None = None, progress: Callable[[int, int], None] | None = None):
    """PIL RGB image: the given layers side by side, each reduced to ``tile`` pixels and labelled with its
    number and z. Its size is checked (:func:`sheet_size`) before anything is decoded; the tiles are drawn
    over the cores (:func:`heoslice.pipeline.parallel.ordered_map`), ``progress(done, total)`` following them."""
    from PIL import Image, ImageDraw

    directory = Path(directory)
    manifest = read_manifest(directory) if manifest is None else manifest
    aspect = layer_aspect(manifest)
    columns, width, height = sheet_size(len(layers), tile, columns, aspect)
    box_width, box_height = tile_box(tile, aspect)
    sheet = Image.new("RGB", (width, height), (200, 200, 200))
    draw = ImageDraw.Draw(sheet)
    tiles = ordered_map(lambda index: np.asarray(layer_image(directory, index, tile, manifest)), layers)
    for position, (index, pixels) in enumerate(zip(layers, tiles)):
        image = Image.fromarray(pixels)
        if progress is not None:
            progress(position + 1, len(layers))
        x = 4 + (position % columns) * (box_width + 4)
        y = 4 + (position // columns) * (box_height + LABEL_HEIGHT + 4)
        sheet.paste(image, (x + (box_width - image.size[0]) // 2, y + LABEL_HEIGHT + (box_height - image.size[1]) // 2))
        z = manifest["layers"][index]["z_mm"]
        draw.text((x + 2, y + 1), f"layer {index}  z {z:.2f} mm", fill=(0, 0, 0))
    return sheet
