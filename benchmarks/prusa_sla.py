"""PrusaSlicer's SLA export as a reference: the print profile for a mesh, reading its .sl1, and
comparing its per-layer solid pixel counts with a heoslice stack.

PrusaSlicer 2.5 (``SLAPrintObjectSteps::slice_model``) cuts the first layer at
``initial_layer_height / 2`` above the bed and every later one at the middle of its layer,
so with ``initial_layer_height = layer_height = h`` layer i is cut at z_bed + (i + 1/2) h,
the same planes as heoslice (z_min + (i + 1/2) h); layers are matched by that height.
``gamma_correction = 0`` makes it threshold each pixel at half coverage instead of
anti-aliasing, so its PNGs hold only 0 and 255.
"""

from __future__ import annotations

import io
import math
import os
import zipfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

MM_PER_INCH = 25.4

INSTALL_HINT = (
    "PrusaSlicer not found: running heoslice alone. To compare, install it, e.g.\n"
    "  sudo apt-get install prusa-slicer        # Debian 12 / Ubuntu (2.5)\n"
    "or download the AppImage from https://www.prusa3d.com/prusaslicer/ and pass --prusa PATH.\n"
    "No display is needed: --export-sla runs headless."
)


@dataclass(frozen=True)
class Display:
    """An SLA display just covering a part plus a margin at a given pixel pitch (mm)."""

    pixels_x: int
    pixels_y: int
    pitch_mm: float

    @property
    def width_mm(self) -> float:
        return self.pixels_x * self.pitch_mm

    @property
    def height_mm(self) -> float:
        return self.pixels_y * self.pitch_mm


def display_for(extents_mm: np.ndarray, dpi: float, margin_mm: float = 1.0) -> Display:
    """The display for a part of (x, y) extents: pitch 25.4 / dpi, part + margin on each side (as heoslice's grid)."""
    pitch = MM_PER_INCH / dpi
    return Display(pixels_x=math.ceil((extents_mm[0] + 2 * margin_mm) / pitch),
                   pixels_y=math.ceil((extents_mm[1] + 2 * margin_mm) / pitch), pitch_mm=pitch)


def sla_ini(display: Display, layer_mm: float, height_mm: float) -> str:
    """The PrusaSlicer config (keys as in ``prusa-slicer --help-sla``): plain part, no supports, pad,
    hollowing, corrections or anti-aliasing; a landscape display so image x is bed x; a bed
    matching the display; a print height limit above the part."""
    w, h = display.width_mm, display.height_mm
    settings = {
        "printer_technology": "SLA",
        "layer_height": layer_mm,
        "initial_layer_height": layer_mm,
        "display_pixels_x": display.pixels_x,
        "display_pixels_y": display.pixels_y,
        "display_width": repr(w),
        "display_height": repr(h),
        "display_orientation": "landscape",
        "display_mirror_x": 0,
        "display_mirror_y": 0,
        "bed_shape": f"0x0,{w!r}x0,{w!r}x{h!r},0x{h!r}",
        "max_print_height": math.ceil(height_mm + 10),
        "supports_enable": 0,
        "pad_enable": 0,
        "hollowing_enable": 0,
        "support_object_elevation": 0,
        "elefant_foot_compensation": 0,
        "absolute_correction": 0,
        "relative_correction": "1,1",
        "material_correction": "1,1,1",
        "gamma_correction": 0,
    }
    return "".join(f"{key} = {value}\n" for key, value in settings.items())


def prusa_command(executable: str, ini: Path, output: Path, model: Path) -> list[str]:
    """The measured PrusaSlicer command line (issue 6's anchor)."""
    return [executable, "--loglevel", "1", "--export-sla", "--load", str(ini), "-o", str(output), str(model)]


def _png_counts(args: tuple[str, list[str]]) -> list[tuple[int, int]]:
    """(solid pixels > 127, grey pixels strictly between 0 and 255) for some PNG layers of an .sl1."""
    archive, names = args
    counts = []
    with zipfile.ZipFile(archive) as sl1:
        for name in names:
            with Image.open(io.BytesIO(sl1.read(name))) as image:
                histogram = np.asarray(image.convert("L").histogram())
            counts.append((int(histogram[128:].sum()), int(histogram[1:255].sum())))
    return counts


def sl1_layer_counts(archive: Path, stride: int = 1, workers: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Per-layer solid and grey pixel counts of an .sl1 (zip of PNG layers), for every ``stride``-th layer.

    Returns (layer indices (k,) int, solid counts (k,) int, grey counts (k,) int); the
    layer index is the PNG's position in name order. PNG decoding dominates, so it runs
    over ``workers`` processes.
    """
    with zipfile.ZipFile(archive) as sl1:
        names = sorted(name for name in sl1.namelist() if name.lower().endswith(".png"))
    chosen = np.arange(0, len(names), stride)
    workers = workers or max(1, len(os.sched_getaffinity(0)))
    parts = np.array_split(chosen, max(1, 4 * workers))
    chunks = [(str(archive), [names[i] for i in part]) for part in parts if len(part)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = [count for chunk in pool.map(_png_counts, chunks) for count in chunk]
    solid = np.array([r[0] for r in results], dtype=np.int64)
    grey = np.array([r[1] for r in results], dtype=np.int64)
    return chosen, solid, grey


@dataclass(frozen=True)
class Agreement:
    """Per-layer solid pixel counts of both stacks compared at matching heights."""

    layers_heoslice: int
    layers_prusa: int
    compared: int
    within: int
    tolerance: float
    worst: list[dict]
    only_heoslice: list[dict]
    only_prusa: list[dict]
    total_difference: float
    median_difference: float
    heoslice_larger: int
    prusa_larger: int
    grey_pixels: int
    spot_checks: list[dict]

    @property
    def ok(self) -> bool:
        """Every compared layer within tolerance and no non-empty layer missing from either stack, except
        heoslice's partial top layer: PrusaSlicer keeps only layers whose top is at or below the part's top."""
        missing = [entry for entry in self.only_heoslice + self.only_prusa
                   if entry["solid_pixels"] > 0 and not entry.get("partial_top")]
        return self.compared > 0 and self.within == self.compared and not missing

    def as_dict(self) -> dict:
        return {**{key: getattr(self, key) for key in self.__dataclass_fields__}, "ok": self.ok}


#: Pixels by which two layers' solid counts may differ whatever their relative difference: on a sliver of a
#: few dozen pixels (the last layer under a part's top), one pixel centre either side of an outline is 3 %.
PIXEL_SLACK = 2


def compare_counts(manifest: dict, prusa_index: np.ndarray, prusa_solid: np.ndarray, prusa_grey: np.ndarray,
                   prusa_total_layers: int, tolerance: float = 0.01,
                   spot_checks: list[dict] | None = None) -> Agreement:
    """Match layers by height above the part's bottom, (i + 1/2) h for both, and compare solid pixel counts.

    The relative difference of a layer is |heoslice - prusa| / max(heoslice, prusa)
    (0 when both are empty); a layer is within when that is at most ``tolerance`` or the counts differ by
    at most PIXEL_SLACK pixels.
    """
    h = float(manifest["layer_height_mm"])
    z0, z1 = (float(value) for value in manifest["z_range_mm"])
    heo_index = np.array([round((entry["z_mm"] - z0) / h - 0.5) for entry in manifest["layers"]], dtype=np.int64)
    heo_solid = np.array([entry["solid_pixels"] for entry in manifest["layers"]], dtype=np.int64)
    common, in_heo, in_prusa = np.intersect1d(heo_index, prusa_index, return_indices=True)
    a, b = heo_solid[in_heo], prusa_solid[in_prusa]
    relative = np.abs(a - b) / np.maximum(np.maximum(a, b), 1)
    order = np.argsort(-relative)[:5]
    worst = [{"layer": int(common[i]), "z_mm": round(float((common[i] + 0.5) * h), 4), "heoslice": int(a[i]),
              "prusa": int(b[i]), "relative": float(relative[i])} for i in order]
    heo_missing = heo_index >= prusa_total_layers
    prusa_missing = ~np.isin(prusa_index, heo_index)
    return Agreement(
        layers_heoslice=len(heo_index),
        layers_prusa=prusa_total_layers,
        compared=len(common),
        within=int(np.count_nonzero((relative <= tolerance) | (np.abs(a - b) <= PIXEL_SLACK))),
        tolerance=tolerance,
        worst=worst,
        only_heoslice=[{"layer": int(i), "solid_pixels": int(n), "partial_top": bool((i + 1) * h > z1 - z0 + 1e-6)}
                       for i, n in zip(heo_index[heo_missing], heo_solid[heo_missing])],
        only_prusa=[{"layer": int(i), "solid_pixels": int(n)}
                    for i, n in zip(prusa_index[prusa_missing], prusa_solid[prusa_missing])],
        total_difference=float((a.sum() - b.sum()) / max(b.sum(), 1)),
        median_difference=float(np.median(relative)) if len(relative) else float("nan"),
        heoslice_larger=int(np.count_nonzero(a > b)),
        prusa_larger=int(np.count_nonzero(a < b)),
        grey_pixels=int(prusa_grey.sum()),
        spot_checks=spot_checks or [],
    )
