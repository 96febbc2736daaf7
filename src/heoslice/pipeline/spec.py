"""What a slice is asked for: the :class:`SliceSpec` (checked when made) and the stage timings it reports.

Errors name the parameter (``layer_height_mm: ...``); the command line maps parameters to its flags.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from heoslice.errors import InputError, shown
from heoslice.grading.halftone import DEFAULT_METHOD, check_method
from heoslice.stack import COMPRESSIONS, DEFAULT_COMPRESSION

if TYPE_CHECKING:  # the grading package loads its kernels and shapely: a one-material slice never imports it
    from heoslice.grading import GradeSpec
    from heoslice.pipeline.parts import PartsPlan
    from heoslice.pipeline.printers import PrinterPreset

MIN_LAYER_MM, MAX_LAYER_MM = 1e-3, 10_000.0
MIN_DPI, MAX_DPI = 1.0, 100_000.0
#: Widest margin and canvas side, mm (10 m: far beyond any build plate).
MAX_MARGIN_MM, MAX_CANVAS_MM = 10_000.0, 10_000.0
#: Most worker processes one slice forks.
MAX_JOBS = 256
#: Largest coordinate a mesh may have after scaling, mm (1 km): every size derived from it stays finite.
MAX_COORDINATE_MM = 1e6
#: Most coordinate scale factor, and least (a part in km, in nanometres).
MIN_SCALE, MAX_SCALE = 1e-6, 1e6


def check_range(parameter: str, value, low: float, high: float, unit: str = "", low_open: bool = False) -> None:
    """Refuse (InputError naming ``parameter``) a value that is not a finite number within [low, high]
    (``low`` excluded with ``low_open``), before any arithmetic is done with it."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{parameter}: must be a number, got {shown(value)}") from None
    inside = (number > low if low_open else number >= low) and number <= high
    if not (np.isfinite(number) and inside):
        bound = f"above {low:g}" if low_open else f"at least {low:g}"
        raise InputError(f"{parameter}: must be {bound} and at most {high:g}{unit}, got {number:g}")


def check_scale(scale: float, bounds: np.ndarray) -> None:
    """Refuse a coordinate scale factor outside MIN_SCALE .. MAX_SCALE, or one that takes a mesh whose bounds
    are ``bounds`` ((2, 3) float, mm) beyond MAX_COORDINATE_MM, before the coordinates are multiplied."""
    check_range("scale", scale, MIN_SCALE, MAX_SCALE)
    largest = float(np.abs(bounds).max()) * float(scale)
    if not largest <= MAX_COORDINATE_MM:
        raise InputError(f"scale: x{float(scale):g} takes the mesh to {largest:g} mm from the origin, "
                         f"beyond the {MAX_COORDINATE_MM:g} mm a slice can hold")


@dataclass(frozen=True)
class SliceSpec:
    """What to slice and how: layer height (mm), resolution (dpi x, y), canvas, encoding, workers.

    ``grade`` asks for graded interiors (:mod:`heoslice.grading`); ``channels`` for one droplet mask per
    material per layer (:mod:`heoslice.grading.halftone`): None (the default) whenever the stack holds more
    than one material, False for an RGBA preview stack instead; ``materials`` is the materials table a
    mesh's colours map to (empty: the built-in M1, M2). :func:`heoslice.pipeline.material_job` settles
    both for a mesh.
    ``parts`` makes the slice a multi-part job (:mod:`heoslice.pipeline.parts`; not graded).
    ``design`` is the coloured model's design (:class:`heoslice.material.design.Design`, its materials as
    the table has them; None: the mesh's own record, if any, is read); ``interior`` what a coloured model's
    solid gets (:data:`heoslice.material.design.INTERIORS`; None: ``field`` for a model with a design,
    ``graded`` with ``grade``'s function, else ``contour``). ``halftone`` is how a graded layer's mix becomes
    droplets (:data:`heoslice.grading.halftone.METHODS`). ``printer`` (a
    :class:`heoslice.pipeline.printers.PrinterPreset`) pads the image width to its multiple and limits the
    materials; its resolution and layer pitch must be the spec's.
    """

    layer_height_mm: float = 0.1
    dpi: tuple[float, float] = (600.0, 600.0)
    margin_mm: float = 1.0
    canvas_mm: tuple[float, float] | None = None
    compression: str = DEFAULT_COMPRESSION
    jobs: int = 0
    grade: GradeSpec | None = None
    channels: bool | None = None
    materials: tuple = ()
    #: Segments sliced and chained at once; bounds memory (a few hundred bytes per segment).
    max_segments: int = 50_000
    parts: PartsPlan | None = None
    design: object | None = None
    interior: str | None = None
    halftone: str = DEFAULT_METHOD
    printer: PrinterPreset | None = None

    def __post_init__(self):
        from heoslice.material.design import INTERIORS

        if self.interior is not None and self.interior not in INTERIORS:
            raise InputError(f"interior: unknown interior {self.interior!r} (choose from {', '.join(INTERIORS)})")
        if self.printer is not None and (tuple(map(float, self.dpi)) != self.printer.dpi
                                         or float(self.layer_height_mm) != self.printer.layer_mm):
            raise InputError(f"printer: {self.printer.name} slices at {self.printer.dpi[0]:g}x{self.printer.dpi[1]:g} "
                             f"dpi and {self.printer.layer_mm:g} mm layers, not {self.dpi[0]:g}x{self.dpi[1]:g} dpi "
                             f"and {self.layer_height_mm:g} mm")
        try:
            check_method(self.halftone)
        except ValueError as err:
            raise InputError(str(err)) from None
        if self.compression not in COMPRESSIONS:
            raise InputError(f"compression: unknown compression {self.compression!r}; "
                             f"choose one of {', '.join(COMPRESSIONS)}")
        check_range("layer_height_mm", self.layer_height_mm, MIN_LAYER_MM, MAX_LAYER_MM, " mm")
        for value in self.dpi:
            check_range("dpi", value, MIN_DPI, MAX_DPI, " dpi")
        check_range("margin_mm", self.margin_mm, 0.0, MAX_MARGIN_MM, " mm")
        for value in self.canvas_mm or ():
            check_range("canvas_mm", value, 0.0, MAX_CANVAS_MM, " mm", low_open=True)
        check_range("jobs", self.jobs, 0, MAX_JOBS, " (0: one per core)")
        check_range("max_segments", self.max_segments, 1, 2**40)
        if self.parts is not None and (self.grade is not None or self.channels):
            raise InputError("grade: a multi-part job is not graded (slice a part on its own to grade it)")
        if self.channels and self.grade is None:
            raise InputError("channels: droplet masks need a graded slice (grade)")
        if self.grade is not None:
            names = [channel_name(material) for material in self.grade.channel_materials()]
            if len(set(names)) != len(names):
                raise InputError(f"materials: material names give the same droplet-mask file names ({names}); "
                                 "rename them")

    def worker_count(self) -> int:
        """Worker processes to use: ``jobs``, or with 0 one per core this process may run on."""
        from heoslice.pipeline.parallel import usable_cores

        return self.jobs if self.jobs > 0 else usable_cores()


def channel_name(material) -> str:
    """The file-name suffix of a material's droplet masks: its name with anything but letters,
    digits and '-' replaced by '-' (e.g. '0,255,0' -> '0-255-0')."""
    return re.sub(r"[^A-Za-z0-9-]", "-", str(material.name)) or "material"


@dataclass
class StageTimes:
    """Seconds spent per stage, summed over the runs of planes and the worker processes (CPU seconds)."""

    slice: float = 0.0
    contours: float = 0.0
    raster: float = 0.0
    encode: float = 0.0
    total: float = 0.0
