"""Printer presets: the grid, layer pitch, padding and material limit a printer takes, in one word
(``heoslice slice --printer j750-27um``), so a stack is sliced (and halftoned) on the printer's own grid.

One table (:data:`PRESETS`), a frozen :class:`PrinterPreset` per row; where each figure comes from is
in ``docs/export-formats.md`` ("Printer presets").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from heoslice.errors import InputError


@dataclass(frozen=True)
class PrinterPreset:
    """One printer mode: its name, the printer, resolution (dpi x, y), layer pitch (mm), the multiple of pixels
    the image width is padded to, and the most model materials it jets in one job."""

    name: str
    printer: str
    dpi: tuple[float, float]
    layer_mm: float
    pad_x_px: int
    max_materials: int


#: Every preset, by name (``--printer``): PolyJet voxel printing's 600 x 300 dpi grid, X padded to 16 pixels.
PRESETS: dict[str, PrinterPreset] = {preset.name: preset for preset in (
    PrinterPreset("j750-27um", "Stratasys J750 / J735, high-mix mode", (600.0, 300.0), 0.027, 16, 6),
    PrinterPreset("j750-14um", "Stratasys J750 / J735, high-quality mode", (600.0, 300.0), 0.014, 16, 6),
    PrinterPreset("j850-27um", "Stratasys J850 / J826, high-mix mode", (600.0, 300.0), 0.027, 16, 6),
    PrinterPreset("j850-14um", "Stratasys J850 / J826, high-quality mode", (600.0, 300.0), 0.014, 16, 6),
    PrinterPreset("connex-30um", "Stratasys Objet Connex3, digital-materials mode", (600.0, 300.0), 0.030, 16, 3),
)}


def printer_preset(name: str) -> PrinterPreset:
    """The preset called ``name``; InputError naming the presets otherwise."""
    preset = PRESETS.get(name)
    if preset is None:
        raise InputError(f"printer: unknown printer {name!r}; choose one of {', '.join(PRESETS)} "
                         "(heoslice slice --printer list)")
    return preset


def presets_table() -> list[str]:
    """The presets as lines of a table: name, resolution, layer, padding, materials, printer."""
    lines = [f"{'printer':<12} {'dpi (x x y)':<12} {'layer':<9} {'x pad':<6} {'materials':<10} mode"]
    for preset in PRESETS.values():
        dpi = f"{preset.dpi[0]:g}x{preset.dpi[1]:g}"
        lines.append(f"{preset.name:<12} {dpi:<12} {preset.layer_mm * 1000:g} um{'':<3} {preset.pad_x_px:<6} "
                     f"{preset.max_materials:<10} {preset.printer}")
    return lines


def printer_grid(grid, preset: PrinterPreset | None):
    """The layer grid (:class:`heoslice.layers.rasterising.Grid`) as the preset's printer takes it: its width padded
    to a multiple of the preset's ``pad_x_px`` (the image grows to the right); unchanged without a preset."""
    if preset is None:
        return grid
    return replace(grid, width=-(-grid.width // preset.pad_x_px) * preset.pad_x_px)


def check_printer_materials(preset: PrinterPreset | None, count: int) -> None:
    """Refuse (InputError) a job of ``count`` droplet-mask materials (0: one material) beyond the most the preset's
    printer jets in one job; nothing to check without a preset."""
    if preset is not None and max(count, 1) > preset.max_materials:
        raise InputError(f"printer: {preset.name} jets at most {preset.max_materials} model materials in one job; "
                         f"this slice has {count}")
