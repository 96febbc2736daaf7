"""Vertical sections: a stack cut at ``x = MM`` or ``y = MM``, every layer's row of pixels in its material
colours, bottom layer at the bottom, drawn at the true aspect ratio (pixel size across, layer height up)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from heoslice.errors import InputError, VerifyError
from heoslice.pipeline.parallel import ordered_map
from heoslice.preview.layer import MAX_PREVIEW_SIDE, _display, _planes, channel_colors, check_size
from heoslice.stack import MANIFEST, layer_strips, read_manifest
from heoslice.stack.packed import SeenLines, layer_files, line_bits

SECTION_PATTERN = re.compile(r"^\s*([xyXY])\s*=\s*([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)\s*$")


def parse_section(text: str) -> tuple[str, float]:
    """('x' or 'y', position mm) from 'x=MM' or 'y=MM'; InputError naming ``section`` otherwise."""
    match = SECTION_PATTERN.match(str(text))
    value = float(match.group(2)) if match else float("nan")
    if not match or not np.isfinite(value):
        raise InputError(f"section: expected x=MM or y=MM, got {str(text)[:40]!r}")
    return match.group(1).lower(), value


def section_line(manifest: dict, axis: str, position_mm: float) -> int:
    """The image column (axis 'x') or row (axis 'y') through ``position_mm``; InputError when outside."""
    image, (px, py) = manifest["image"], manifest["pixel_size_mm"]
    x_left, y_top = image["origin_mm"]
    if axis == "x":
        line, count = np.floor((position_mm - x_left) / px), image["width"]
        low, high = x_left, x_left + image["width"] * px
    else:
        line, count = np.floor((y_top - position_mm) / py), image["height"]
        low, high = y_top - image["height"] * py, y_top
    if not 0 <= line < count:
        raise InputError(f"section: {axis}={position_mm:g} mm lies outside the stack ({axis} from {low:.6g} mm up "
                         f"to, not including, {high:.6g} mm: the image's edges)")
    return int(line)


def _line_planes(directory: Path, manifest: dict, index: int, axis: str, line: int, kind: str) -> np.ndarray:
    """(n, C) float32: the feature planes of :func:`heoslice.preview.layer._planes` along the section line of one
    layer. A 1-bit layer is read along the line alone (:func:`heoslice.stack.packed.line_bits`: for a y cut only
    the strip holding it); a layer with droplet masks is drawn from its masks, checked on the line against its
    solid layer (each solid pixel in exactly one mask, no mask pixel outside the solid: verify's rule, where the
    preview draws); other layers strip by strip."""
    with_channels = kind == "channels"
    if kind in ("bilevel", "channels") and manifest["image"].get("mode", "1") in ("1", "L"):
        layer, masks = layer_files(directory, manifest, index, channels=with_channels)
        seen: SeenLines = {}
        solid = line_bits(layer, manifest["mask"] == "alpha", axis, line, seen)
        lines = [line_bits(mask, False, axis, line, seen) for mask in masks] or [solid]
        if with_channels:
            held = np.sum(lines, axis=0, dtype=np.uint8)
            wrong = np.flatnonzero(held != solid)
            if len(wrong):
                where = "in two droplet masks" if held[wrong[0]] > 1 else (
                    "in no droplet mask" if held[wrong[0]] == 0 else "in a droplet mask outside the solid")
                raise VerifyError(f"layer {index}: a pixel of the section is {where}")
        return np.stack(lines, axis=-1).astype(np.float32)
    alpha = manifest["mask"] == "alpha"
    parts = []
    for row, pixels, strip_masks in layer_strips(directory, manifest, index, channels=with_channels):
        if axis == "y" and not row <= line < row + len(pixels):
            continue
        planes = _planes(kind, pixels, strip_masks, index, alpha)
        parts.append(np.stack([plane[line - row] if axis == "y" else plane[:, line] for plane in planes], axis=-1))
    return np.concatenate(parts).astype(np.float32)


def _layer_line(directory: Path, manifest: dict, index: int, axis: str, line: int, factor: int) -> np.ndarray:
    """(ceil(n / factor), 3) uint8: the display colours along the section line of one layer, box-reduced."""
    entry = manifest["layers"][index]
    with_channels = bool(entry.get("channels"))
    colors = channel_colors(manifest, index, Path(directory) / MANIFEST) if with_channels else None
    samples = {"1": "bilevel", "L": "bilevel", "RGB": "rgb", "RGBA": "rgba"}[manifest["image"].get("mode", "1")]
    kind = "channels" if with_channels else samples
    means = _line_planes(directory, manifest, index, axis, line, kind)
    if factor > 1:
        starts = np.arange(0, len(means), factor)
        counts = np.diff(np.append(starts, len(means))).astype(np.float32)[:, None]
        means = np.add.reduceat(means, starts, axis=0) / counts
    return _display(kind, colors)(means[None])[0]


def section_grid(manifest: dict, axis: str, size: int | None = None) -> tuple[tuple[int, int], int, np.ndarray]:
    """How a section across ``axis`` is drawn: its (width, height) px at the true aspect ratio (layer height
    against pixel size), its longer side at most ``size`` (default MAX_PREVIEW_SIDE); the box factor its line is
    reduced by; and the stack layer each of its rows shows, (height,) from the bottom row up (the layers it
    reads)."""
    size = check_size(size)
    image, (px, py), h = manifest["image"], manifest["pixel_size_mm"], manifest["layer_height_mm"]
    across, pixel = (image["height"], py) if axis == "x" else (image["width"], px)
    layers = len(manifest["layers"])
    true_height = layers * h / pixel
    scale = min(1.0, size / max(across, true_height))
    width_out, height_out = max(1, round(across * scale)), max(1, round(true_height * scale))
    factor = max(1, across // max(width_out, 1))
    sources = np.clip(np.floor((np.arange(height_out) + 0.5) / height_out * layers).astype(np.int64), 0, layers - 1)
    return (width_out, height_out), factor, sources


def section_image(directory: Path, axis: str, position_mm: float, size: int | None = None,
                  manifest: dict | None = None, progress: Callable[[int, int], None] | None = None):
    """PIL RGB image of the vertical section at ``axis`` = ``position_mm`` (mm): one row per layer, top layer at
    the top, stretched to the true aspect ratio (layer height against pixel size) and reduced so its longer
    side is at most ``size`` (default MAX_PREVIEW_SIDE). Only the layers drawn are read, over the cores
    (:func:`heoslice.pipeline.parallel.ordered_map`); ``progress(done, total)`` follows them."""
    from PIL import Image

    directory = Path(directory)
    manifest = read_manifest(directory) if manifest is None else manifest
    line = section_line(manifest, axis, position_mm)
    (width_out, height_out), factor, sources = section_grid(manifest, axis, size)
    drawn = np.unique(sources).tolist()
    lines = {}
    for done, (index, pixels) in enumerate(ordered_map(
            lambda index: (index, _layer_line(directory, manifest, index, axis, line, factor)), drawn), 1):
        lines[index] = pixels
        if progress is not None:
            progress(done, len(drawn))
    rows = np.stack([lines[int(index)] for index in sources[::-1]])
    return Image.fromarray(rows).resize((width_out, height_out), Image.Resampling.BOX)


def annotated_section_image(directory: Path, axis: str, position_mm: float, size: int | None = None,
                            manifest: dict | None = None, progress: Callable[[int, int], None] | None = None):
    """:func:`section_image` with a footer (:func:`heoslice.preview.annotate.annotate`): the cut's position and
    the layers' z range, the legend of the stack's materials and a scale bar in mm (the section is drawn at
    its true aspect ratio, so the bar holds up and across)."""
    from heoslice.preview.annotate import annotate, legend_of
    from heoslice.preview.layer import SOLID_GREY

    manifest = read_manifest(Path(directory)) if manifest is None else manifest
    image = section_image(directory, axis, position_mm, size, manifest, progress)
    across_px, pixel = ((manifest["image"]["height"], manifest["pixel_size_mm"][1]) if axis == "x"
                        else (manifest["image"]["width"], manifest["pixel_size_mm"][0]))
    layers = manifest["layers"]
    title = (f"section {axis} = {position_mm:g} mm; layers 0..{len(layers) - 1}, "
             f"z {layers[0]['z_mm']:.2f}..{layers[-1]['z_mm']:.2f} mm")
    return annotate(image, title, legend_of(manifest, SOLID_GREY), image.size[0] / (across_px * pixel))


__all__ = ["MAX_PREVIEW_SIDE", "annotated_section_image", "parse_section", "section_image", "section_line"]
