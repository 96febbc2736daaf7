"""What a slice is asked for: the :class:`SliceSpec` (checked when made) and the stage timings it reports.

Errors name the parameter (``layer_height_mm: ...``); the command line maps parameters to its flags.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError
from heoslice.grading import GradeSpec
from heoslice.stack import COMPRESSIONS, DEFAULT_COMPRESSION

MIN_LAYER_MM = 1e-3
MIN_DPI, MAX_DPI = 1.0, 100_000.0


@dataclass(frozen=True)
class SliceSpec:
    """What to slice and how: layer height (mm), resolution (dpi x, y), canvas, encoding, workers.

    ``grade`` asks for graded interiors (:mod:`heoslice.grading`), ``channels`` for one
    droplet mask per material per layer (:mod:`heoslice.grading.halftone`; needs ``grade``).
    """

    layer_height_mm: float = 0.1
    dpi: tuple[float, float] = (600.0, 600.0)
    margin_mm: float = 1.0
    canvas_mm: tuple[float, float] | None = None
    compression: str = DEFAULT_COMPRESSION
    jobs: int = 0
    base_color: tuple[int, int, int] = (255, 255, 255)
    grade: GradeSpec | None = None
    channels: bool = False
    #: Segments sliced and chained at once; bounds memory (a few hundred bytes per segment).
    max_segments: int = 50_000

    def __post_init__(self):
        if self.compression not in COMPRESSIONS:
            raise InputError(f"compression: unknown compression {self.compression!r}; "
                             f"choose one of {', '.join(COMPRESSIONS)}")
        if not (np.isfinite(self.layer_height_mm) and self.layer_height_mm >= MIN_LAYER_MM):
            raise InputError(f"layer_height_mm: layer height must be a number of at least {MIN_LAYER_MM} mm, "
                             f"got {self.layer_height_mm}")
        if not (np.isfinite(self.margin_mm) and self.margin_mm >= 0):
            raise InputError(f"margin_mm: must be a finite number >= 0, got {self.margin_mm}")
        if not all(np.isfinite(d) and MIN_DPI <= d <= MAX_DPI for d in self.dpi):
            raise InputError(f"dpi: each resolution must be between {MIN_DPI} and {MAX_DPI}, got {self.dpi}")
        if self.canvas_mm is not None and not all(np.isfinite(v) and v > 0 for v in self.canvas_mm):
            raise InputError(f"canvas_mm: width and height must be finite and positive, got {self.canvas_mm}")
        if self.jobs < 0:
            raise InputError(f"jobs: must be 0 (all cores) or more, got {self.jobs}")
        if self.channels and self.grade is None:
            raise InputError("channels: droplet masks need a graded slice (grade)")
        if self.grade is not None:
            names = [channel_name(material) for material in self.grade.channel_materials()]
            if len(set(names)) != len(names):
                raise InputError(f"materials: material names give the same droplet-mask file names ({names}); "
                                 "rename them")

    def worker_count(self) -> int:
        """Worker processes to use: ``jobs``, or with 0 one per core this process may run on."""
        return self.jobs if self.jobs > 0 else max(1, len(os.sched_getaffinity(0)))


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
