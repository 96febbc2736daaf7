"""What makes a preview explain itself: a footer under the drawn layer or section with its title (layer
number and z, or the cut's position), a legend of the materials in their display colours, and a scale bar
in mm, drawn with Pillow's default font."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Footer colours and spacing (px): text and bar black on light grey (a white material stays visible), swatches
#: outlined in black.
FOOTER_BACKGROUND = (230, 230, 230)
INK = (0, 0, 0)
PAD, SWATCH, LINE_GAP, BAR_HEIGHT = 4, 10, 4, 5
#: The scale bar is a 1, 2 or 5 x 10^k mm length at most this fraction of the drawn width.
BAR_FRACTION = 0.4
#: Narrowest footer, px: a small preview gets a footer wider than itself rather than clipped text.
MIN_FOOTER_WIDTH = 200


@dataclass(frozen=True, slots=True)
class Legend:
    """The materials a preview shows: (name, display colour (r, g, b)) each, in drawing order."""

    entries: tuple[tuple[str, tuple[int, int, int]], ...]


def legend_of(manifest: dict, solid_colour: tuple[int, int, int]) -> Legend:
    """The legend of a stack: its droplet masks' materials (or an RGBA stack's graded materials) in their
    ``grading.materials`` colours, else the one solid material in ``solid_colour``."""
    grading = manifest.get("grading") if isinstance(manifest.get("grading"), dict) else {}
    colours = {m.get("name"): m.get("color") for m in grading.get("materials") or [] if isinstance(m, dict)}
    names: list[str] = []
    for entry in manifest["layers"]:
        for channel in entry.get("channels") or []:
            if channel.get("material") not in names:
                names.append(channel.get("material"))
    if not names and manifest["image"].get("mode", "1") == "RGBA":
        names = [name for name in colours if isinstance(name, str)]
    entries = tuple((str(name), tuple(int(v) for v in colours[name])) for name in names
                    if isinstance(colours.get(name), list) and len(colours[name]) == 3)
    return Legend(entries or (("solid", tuple(solid_colour)),))


def scale_bar_mm(px_per_mm: float, width_px: int) -> float:
    """The longest 1, 2 or 5 x 10^k mm whose bar fits in BAR_FRACTION of ``width_px`` at ``px_per_mm``."""
    room = max(1.0, BAR_FRACTION * width_px) / px_per_mm
    exponent = math.floor(math.log10(room))
    for step in (5, 2, 1):
        if step * 10.0 ** exponent <= room:
            return step * 10.0 ** exponent
    return 10.0 ** exponent


def wrapped(text: str, width: float, length) -> list[str]:
    """``text`` broken at spaces into lines of at most ``width`` px as ``length(text)`` measures them (a word
    longer than a line gets a line of its own)."""
    lines: list[str] = []
    for word in text.split(" "):
        if lines and length(f"{lines[-1]} {word}") <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return lines or [""]


def annotate(image, title: str, legend: Legend, px_per_mm: float):
    """``image`` (PIL RGB) with a footer below it: ``title``, the legend's swatches and names, and a scale bar
    of :func:`scale_bar_mm` mm, round(mm x ``px_per_mm``) px long (``px_per_mm`` across the drawn image)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    text_height = max(SWATCH, probe.textbbox((0, 0), "Ag0", font=font)[3])
    width = max(image.size[0], MIN_FOOTER_WIDTH)
    placed, x, line = [], PAD, 0
    for name, colour in legend.entries:
        span = SWATCH + 3 + int(probe.textlength(name, font=font)) + 2 * PAD
        if x > PAD and x + span > width:
            x, line = PAD, line + 1
        placed.append((x, line, name, colour))
        x += span
    titled = wrapped(title, width - 2 * PAD, lambda text: probe.textlength(text, font=font))
    lines = len(titled) + (line + 1) + 1
    footer = PAD + lines * (text_height + LINE_GAP) + PAD
    canvas = Image.new("RGB", (width, image.size[1] + footer), FOOTER_BACKGROUND)
    canvas.paste(image, (0, 0))
    draw = ImageDraw.Draw(canvas)
    top = image.size[1] + PAD
    for number, text in enumerate(titled):
        draw.text((PAD, top + number * (text_height + LINE_GAP)), text, fill=INK, font=font)
    top += (len(titled) - 1) * (text_height + LINE_GAP)
    for x, line, name, colour in placed:
        y = top + (1 + line) * (text_height + LINE_GAP)
        draw.rectangle([x, y, x + SWATCH - 1, y + SWATCH - 1], fill=tuple(colour), outline=INK)
        draw.text((x + SWATCH + 3, y), name, fill=INK, font=font)
    millimetres = scale_bar_mm(px_per_mm, image.size[0])
    length = max(1, round(millimetres * px_per_mm))
    y = top + (lines - len(titled)) * (text_height + LINE_GAP)
    draw.rectangle([PAD, y + 2, PAD + length - 1, y + 1 + BAR_HEIGHT], fill=INK)
    draw.text((PAD + length + 6, y), f"{millimetres:g} mm", fill=INK, font=font)
    return canvas

