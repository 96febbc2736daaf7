"""heoslice.preview.annotate through the previews: a layer's and a section's footer say what they show (the
title drawn exactly), carry each material's display colour and a scale bar whose length in pixels follows
the stack's dpi; contact sheets fit their tiles to the part's aspect."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import in_process
from PIL import Image, ImageDraw, ImageFont

from heoslice import procedural
from heoslice.preview import annotated_layer_image, annotated_section_image, contact_sheet, layer_image
from heoslice.preview.annotate import FOOTER_BACKGROUND, INK, PAD, SWATCH, scale_bar_mm
from heoslice.stack import read_manifest

DPI = 300.0


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """A graded ball (white M1 to green M2, droplet masks) 12 mm wide at 300 dpi, 1 mm layers."""
    folder = tmp_path_factory.mktemp("annotate")
    procedural.sphere(6.0, subdivisions=3).export(folder / "ball.ply")
    assert in_process("slice", folder / "ball.ply", "--layer", "1", "--dpi", DPI, "--grade", "linear", "--to",
                      "0,255,0", "--channels", "-o", folder / "stack") == 0
    return folder / "stack"


def longest_ink_run(footer: np.ndarray) -> int:
    """Longest horizontal run of ink pixels in any row of a footer ((h, w, 3) uint8): the scale bar."""
    best = 0
    for row in np.all(footer == INK, axis=-1):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
        if len(edges):
            best = max(best, int((edges[1::2] - edges[::2]).max()))
    return best


def title_drawn(annotated: np.ndarray, top: int, title: str) -> bool:
    """Whether the footer's first lines show exactly ``title`` in Pillow's default font: on one line, or broken at
    spaces where the footer is too narrow for it, every line within the footer."""
    from heoslice.preview.annotate import LINE_GAP, wrapped

    font = ImageFont.load_default()
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    height = probe.textbbox((0, 0), "Ag0", font=font)[3]
    lines = wrapped(title, annotated.shape[1] - 2 * PAD, lambda text: probe.textlength(text, font=font))
    if " ".join(lines) != title or any(probe.textlength(line, font=font) > annotated.shape[1] - 2 * PAD
                                       for line in lines if " " in line):
        return False
    for number, line in enumerate(lines):
        reference = Image.new("RGB", (annotated.shape[1], height), FOOTER_BACKGROUND)
        ImageDraw.Draw(reference).text((PAD, 0), line, fill=INK, font=font)
        expected = np.asarray(reference)
        at = top + PAD + number * (max(SWATCH, height) + LINE_GAP)
        if not (expected != FOOTER_BACKGROUND).any() or not np.array_equal(annotated[at:at + height], expected):
            return False
    return True


def check_bar(footer: np.ndarray, drawn_width: int, px_per_mm: float) -> None:
    """The scale bar is a 1, 2 or 5 x 10^k mm length drawn round(mm x px/mm) px long, the longest such length
    within 40 % of the drawn width."""
    millimetres = scale_bar_mm(px_per_mm, drawn_width)
    assert longest_ink_run(footer) == round(millimetres * px_per_mm)
    mantissa = millimetres / 10 ** np.floor(np.log10(millimetres))
    assert round(mantissa, 9) in (1.0, 2.0, 5.0)
    assert millimetres * px_per_mm <= 0.4 * drawn_width
    bigger = {1.0: 2.0, 2.0: 5.0, 5.0: 10.0}[round(mantissa, 9)] * millimetres / mantissa
    assert bigger * px_per_mm > 0.4 * drawn_width


def check_legend(footer: np.ndarray, manifest: dict) -> None:
    """Every material of the stack shows as a swatch of its exact display colour."""
    for material in manifest["grading"]["materials"]:
        count = int(np.all(footer == material["color"], axis=-1).sum())
        assert count >= (SWATCH - 2) ** 2, material


def test_layer_preview_says_which_layer_its_materials_and_its_scale(graded):
    """The layer is drawn unchanged at the top left; under it the title 'layer N (of 0..M), z Z mm', a swatch
    per material in its colour and a scale bar of 25.4 / dpi mm per pixel (full size and reduced)."""
    manifest = read_manifest(graded)
    index = len(manifest["layers"]) // 2
    for size in (None, 64):
        plain = np.asarray(layer_image(graded, index, size))
        annotated = np.asarray(annotated_layer_image(graded, index, size))
        height, width = plain.shape[:2]
        assert np.array_equal(annotated[:height, :width], plain)
        z = manifest["layers"][index]["z_mm"]
        assert title_drawn(annotated, height, f"layer {index} (of 0..{len(manifest['layers']) - 1}), z {z:.3f} mm")
        check_legend(annotated[height:], manifest)
        px_per_mm = width / manifest["image"]["width"] * DPI / 25.4
        check_bar(annotated[height:], width, px_per_mm)


def test_section_preview_says_where_it_cuts_and_its_scale(graded):
    """A section's footer names the cut and the layers' z range, the materials and a scale bar across."""
    manifest = read_manifest(graded)
    annotated = np.asarray(annotated_section_image(graded, "x", 0.0))
    from heoslice.preview import section_image

    plain = np.asarray(section_image(graded, "x", 0.0))
    height, width = plain.shape[:2]
    assert np.array_equal(annotated[:height, :width], plain)
    layers = manifest["layers"]
    assert title_drawn(annotated, height, f"section x = 0 mm; layers 0..{len(layers) - 1}, "
                                          f"z {layers[0]['z_mm']:.2f}..{layers[-1]['z_mm']:.2f} mm")
    check_legend(annotated[height:], manifest)
    check_bar(annotated[height:], width, width / manifest["image"]["height"] * DPI / 25.4)


def test_a_wide_parts_sheet_is_mostly_part(tmp_path):
    """A 60 x 10 mm plate's contact sheet: tiles as wide as the part, so under 40 % of the sheet is the grey
    background (square tiles left over 80 %), every tile holding its layer."""
    plate = procedural.box(extents=(60.0, 10.0, 3.0))
    plate.apply_translation(-plate.bounds[0])
    plate.export(tmp_path / "plate.ply")
    assert in_process("slice", tmp_path / "plate.ply", "--layer", "0.2", "--dpi", "200", "-o", tmp_path / "s") == 0
    count = len(json.loads((tmp_path / "s" / "manifest.json").read_text())["layers"])
    sheet = np.asarray(contact_sheet(tmp_path / "s", list(range(count))))  # the default 256 px tiles
    grey = np.all(sheet == 200, axis=-1).mean()
    assert grey < 0.4, grey
    assert sheet.shape[1] > sheet.shape[0] / 2  # laid out about square, not one tall column


def test_a_long_title_on_a_narrow_picture_wraps_within_the_footer():
    """A title wider than a narrow preview's footer is broken at spaces onto lines that each fit (none cut at the
    edge), every word kept in order, and the footer grows to hold them."""
    from heoslice.preview.annotate import Legend, annotate, wrapped

    font = ImageFont.load_default()
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    title = "section x = 0 mm; layers 0..92, z 91.80..183.80 mm"
    lines = wrapped(title, 200 - 2 * PAD, lambda text: probe.textlength(text, font=font))
    assert len(lines) > 1 and " ".join(lines) == title
    assert all(probe.textlength(line, font=font) <= 200 - 2 * PAD for line in lines)
    one = annotate(Image.new("RGB", (120, 60)), "short", Legend((("M1", (255, 255, 255)),)), 1.0)
    many = annotate(Image.new("RGB", (120, 60)), title, Legend((("M1", (255, 255, 255)),)), 1.0)
    assert many.size[0] == one.size[0] and many.size[1] > one.size[1]
