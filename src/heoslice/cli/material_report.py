"""``verify``'s delivered-material report: computed by :mod:`heoslice.stack.report`, shown here as text lines and
as the ``delivered`` object of ``verify --json``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from heoslice.errors import InputError, MalformedDesign, VerifyError
from heoslice.stack import read_manifest
from heoslice.stack.report import (
    WINDOW_MM,
    MaterialReport,
    PartShare,
    material_names,
    least_solid,
    material_report,
    part_shares,
    pixel_position,
    preview_design,
    reduce_tallies,
    share_bands,
    window_grid,
)
from heoslice.stack.recorded_design import R_BANDS, field_comparison

if TYPE_CHECKING:  # the mesh stage loads only for a mesh's parts: a plain verify starts quicker
    from heoslice.mesh import Mesh

#: Bands ``verify`` compares: of the designed target share with --design (10: 0-10 %, ..., 90-100 %), of r with a
#: recorded design (the same count, :data:`heoslice.stack.recorded_design.R_BANDS`).
SHARE_BANDS = R_BANDS
#: A band's or window's delivered share further than this from the designed one fails verify (a problem line).
DESIGN_TOLERANCE = 0.02


def designed_part_volumes(manifest: dict, mesh: Mesh | None) -> list[float] | None:
    """Each part's designed volume (mm^3, in the manifest's part order) of a multi-part stack: its volume less what parts of a lower
    rank take where they overlap, from its --mesh assembly when given, else as the manifest records it; None
    without parts, or when neither knows."""
    parts = manifest.get("parts")
    if not parts:
        return None
    volumes = None
    if mesh is not None and len(mesh.parts) == len(parts):
        from heoslice.mesh import ranked_part_volumes_mm3

        volumes = ranked_part_volumes_mm3(mesh, sorted(range(len(parts)), key=lambda label: parts[label]["rank"]))
    if volumes is None:
        volumes = [part.get("volume_mm3") for part in parts]
    if any(volume is None for volume in volumes):
        return None
    return [float(volume) for volume in volumes]


def design_of_preview(stack: Path, manifest: dict, preview: Path):
    """The design read from ``preview``, the --rgba stack of the same slice (:func:`preview_design`);
    InputError naming --design when it cannot be one for ``stack``."""
    materials = (manifest.get("grading") or {}).get("materials") or []
    if len(materials) != 2 or not all(isinstance(m.get("color"), list) for m in materials):
        raise InputError(f"--design: {stack} is not a stack of two coloured materials; a preview stack gives the "
                         "design of a two-material graded or coloured stack only")
    try:
        other = read_manifest(preview)
    except VerifyError as err:
        raise InputError(f"--design: {err}") from None
    if other["image"].get("mode") != "RGBA" or len(other["layers"]) != len(manifest["layers"]):
        raise InputError(f"--design: {preview} is not the --rgba preview stack of the same slice: it is "
                         f"{other['image'].get('mode')} with {len(other['layers'])} layers, and {stack}'s preview "
                         f"would be RGBA with {len(manifest['layers'])}")
    try:
        return preview_design(preview, manifest, [m["color"] for m in materials], other)
    except ValueError as err:
        raise InputError(f"--design: {preview}: {err}") from None


def recorded_target(manifest: dict) -> int:
    """The mask index of the material the stack's design is a share of, as its manifest records it: the
    grading's target (``--to``), else its recorded design's target (a coloured model), else the second mask
    (a stack that records neither)."""
    names = material_names(manifest)
    grading = manifest.get("grading") or {}
    for target in (grading.get("target"), (grading.get("design") or {}).get("target")):
        if isinstance(target, dict) and target.get("name") in names:
            return names.index(target["name"])
    return len(names) - 1


@dataclass(frozen=True)
class Comparison:
    """What the report's design came from: ``preview`` (--design) or ``manifest`` (the recorded design of a
    field-interior stack), what its bands are of (``share``: the designed target share; ``r``) and the target's
    mask index."""

    source: str
    bands_of: str
    target: int


class RecordedWork:
    """``verify_stack``'s extra work (:data:`heoslice.stack.verify.AlsoWork`) on a field-interior stack: each layer,
    as it is checked, tallied against the design its manifest records (:meth:`RecordedField.tally`), in the process
    that checked it, so the comparison reads no file twice. ``recorded`` is the design once found (None: none;
    ``problem`` says why a record that cannot be read fails the stack, ``warning`` why a design that cannot be
    evaluated, its reference surface missing or changed, is not compared)."""

    def __init__(self, stack: Path):
        self.stack, self.recorded, self.warning, self.problem = stack, None, None, None

    def __call__(self, manifest: dict):
        try:
            self.recorded = field_comparison(self.stack, manifest)
        except MalformedDesign as err:
            self.problem = f"{err}: what the stack delivers cannot be compared with its design"
            return None
        except InputError as err:
            self.warning = f"{err}; the delivered material is not compared with the design"
            return None
        return None if self.recorded is None else (range(len(manifest["layers"])), self.recorded.tally)


def compute(stack: Path, manifest: dict, mesh: Mesh | None, preview: Path | None, warnings: list[str],
            problems: list[str], recorded: RecordedWork | None = None, tallies: dict | None = None):
    """The report of a verified stack and its parts against their design (None without): (report, parts,
    comparison). A field-interior stack is compared with the design its manifest records (bands of r) unless
    --design is given: ``recorded`` did that work while the stack was verified, its layers' tallies in
    ``tallies`` (by layer); when that design cannot be evaluated (its reference surface missing or changed) one
    line is added to ``warnings`` and the design is not compared; a delivered material off its design is a line in
    ``problems`` (what prints must be what was designed)."""
    comparison = None
    if preview is not None:
        target = recorded_target(manifest)
        report = material_report(stack, manifest, design_of_preview(stack, manifest, preview),
                                 share_bands(SHARE_BANDS, target), SHARE_BANDS)
        comparison = Comparison("preview", "share", target)
    elif recorded is not None and recorded.recorded is not None and tallies is not None:
        report = reduce_tallies(manifest, [tallies[index] for index in sorted(tallies)])
        comparison = Comparison("manifest", "r", recorded.recorded.target)
    else:
        warnings += [recorded.warning] if recorded is not None and recorded.warning else []
        problems += [recorded.problem] if recorded is not None and recorded.problem else []
        report = material_report(stack, manifest)
    designed = designed_part_volumes(manifest, mesh)
    parts = None if designed is None else part_shares(manifest, report, designed)
    off = design_mismatch(report, comparison, manifest)
    problems += [f"{stack}: {off}"] if off else []
    return report, parts, comparison


def design_mismatch(report: MaterialReport, comparison: Comparison | None, manifest: dict) -> str | None:
    """A line when the delivered material strays more than DESIGN_TOLERANCE from the design in a band or
    in the worst window, else None."""
    if comparison is None:
        return None
    least = least_solid(window_grid(manifest))
    off = [f"band {b.band} of {'r' if comparison.bands_of == 'r' else 'designed share'} by "
           f"{100 * b.difference:.2f} points" for b in report.bands
           if b.difference > DESIGN_TOLERANCE and b.voxels >= least]
    worst = report.worst
    if worst is not None and abs(worst.difference) > DESIGN_TOLERANCE:
        off.append(f"the worst {window_size_text(manifest)} window (layer {worst.layer}) by "
                   f"{100 * abs(worst.difference):.2f} points")
    if not off:
        return None
    return (f"the delivered material differs from the design by more than {100 * DESIGN_TOLERANCE:g} points: "
            + "; ".join(off))


def window_centre_mm(manifest: dict, pixel: tuple[int, int]) -> tuple[float, float]:
    """Model coordinates (x, y) mm of the centre of the window whose top-left pixel is (row, column)."""
    rows, columns = window_grid(manifest).size
    return pixel_position(manifest, (pixel[0] + (rows - 1) / 2, pixel[1] + (columns - 1) / 2))


def window_step_text(manifest: dict) -> str:
    """The step between the windows verify compares, 'S mm' (or 'SX x SY mm' when x and y differ)."""
    return _mm_text(manifest, window_grid(manifest).step)


def window_size_text(manifest: dict) -> str:
    """The side of the windows verify compares: '2 mm' (WINDOW_MM), or on a stack coarser than 600 dpi, whose
    windows are larger (:data:`heoslice.stack.report.WINDOW_LEAST_PIXELS`), 'S mm' or 'SX x SY mm'."""
    size, (px, py) = window_grid(manifest).size, manifest["pixel_size_mm"]
    if size == (max(1, round(WINDOW_MM / py)), max(1, round(WINDOW_MM / px))):
        return f"{WINDOW_MM:g} mm"
    return _mm_text(manifest, size)


def _mm_text(manifest: dict, pixels: tuple[int, int]) -> str:
    """(rows, columns) pixels of the stack in mm, 'S mm' or 'SX x SY mm'."""
    px, py = manifest["pixel_size_mm"]
    x, y = f"{pixels[1] * px:.3g}", f"{pixels[0] * py:.3g}"
    return f"{x} mm" if x == y else f"{x} x {y} mm"


def as_json(manifest: dict, report: MaterialReport, parts: tuple[PartShare, ...] | None,
            comparison: Comparison | None = None) -> dict:
    """The ``delivered`` object of ``verify --json``."""
    worst = report.worst
    names = [m.name for m in report.materials]
    target = -1 if comparison is None else comparison.target
    window = None
    if worst is not None:
        grid = window_grid(manifest)
        (rows, columns), (row_step, column_step) = grid.size, grid.step
        px, py = manifest["pixel_size_mm"]
        window = {"layer": worst.layer, "pixel": [worst.pixel[1], worst.pixel[0]],
                  "centre_mm": list(window_centre_mm(manifest, worst.pixel)), "size_mm": [columns * px, rows * py],
                  "step_mm": [column_step * px, row_step * py],
                  "solid_pixels": worst.solid, "material": names[worst.material],
                  "designed_share": worst.designed, "delivered_share": worst.delivered,
                  "difference": worst.difference}
    return {
        "solid": {"voxels": report.solid_voxels, "volume_mm3": report.solid_mm3},
        "materials": [{"name": m.name, "voxels": m.voxels, "volume_mm3": m.volume_mm3, "share": m.share}
                      for m in report.materials],
        "parts": None if parts is None else [
            {"parts": list(p.parts), "material": p.material, "designed_mm3": p.designed_mm3,
             "delivered_mm3": p.delivered_mm3, "designed_share": p.designed, "delivered_share": p.delivered,
             "difference": p.difference} for p in parts],
        "worst_window": window,
        "design": None if comparison is None else {"from": comparison.source, "bands_of": comparison.bands_of,
                                                    "target": names[target]},
        "bands": [{"designed_share_of": names[target], "band": [b.band / SHARE_BANDS, (b.band + 1) / SHARE_BANDS],
                   "voxels": b.voxels, "designed": dict(zip(names, b.designed)),
                   "delivered": dict(zip(names, b.delivered)), "difference": b.difference,
                   "judged": b.voxels >= least_solid(window_grid(manifest))} for b in report.bands],
    }


def _percent(share: float) -> str:
    return f"{100 * share:.2f} %"


def text_lines(manifest: dict, report: MaterialReport, parts: tuple[PartShare, ...] | None,
               comparison: Comparison | None = None) -> list[str]:
    """The report as indented text lines, under verify's OK line."""
    lines = [f"  {m.name}: {m.voxels} voxels, {m.volume_mm3:.6g} mm^3, {_percent(m.share)} of the solid"
             for m in report.materials]
    for part in parts or ():
        lines.append(f"  part {', '.join(part.parts)} ({part.material}): designed {_percent(part.designed)}, "
                     f"delivered {_percent(part.delivered)} ({100 * part.difference:+.2f} points)")
    worst = report.worst
    if worst is not None:
        x, y = window_centre_mm(manifest, worst.pixel)
        lines.append(f"  worst {window_size_text(manifest)} window: layer {worst.layer}, centred at x {x:.4g}, y {y:.4g} mm: "
                     f"{report.materials[worst.material].name} designed {_percent(worst.designed)}, "
                     f"delivered {_percent(worst.delivered)} ({100 * worst.difference:+.2f} points); "
                     f"windows every {window_step_text(manifest)}")
    elif comparison is not None and report.solid_voxels:
        lines.append(f"  no {window_size_text(manifest)} window is half solid: the design is compared per band only")
    index = -1 if comparison is None else comparison.target
    target = report.materials[index].name
    least = least_solid(window_grid(manifest))
    for band in report.bands:
        low, high = 100 * band.band // SHARE_BANDS, 100 * (band.band + 1) // SHARE_BANDS
        what = (f"r {low / 100:.1f}-{high / 100:.1f}" if comparison is not None and comparison.bands_of == "r"
                else f"designed {target} {low}-{high} %")
        few = (f" (fewer voxels than a compared window's {least}: not judged)"
               if comparison is not None and band.voxels < least else "")
        lines.append(f"  {what}: {band.voxels} voxels, {target} designed "
                     f"{_percent(band.designed[index])}, delivered {_percent(band.delivered[index])}{few}")
    return lines
