"""Grading inside a label by distance, as the paper grades a mesh (issue 45): the materials file's [grade]
table, and each graded label's 3D material field.

::

    [grade.liver]                # a printed label (value or name, as in [labels]); its [labels] material is M1
    to = "cells"                 # M2 of eq. 1: f(r) is its share
    toward = "liver_tumor"       # r measured from this label's surface; omitted: from the label's own boundary
                                 # (a key naming several labels: each from its own)
    function = "linear"          # f(r): heoslice color's functions (alpha, beta, lam, periods, expression)
    range = [0.0, 20.0]          # mm mapped to r = 0 and r = 1; omitted: 0 .. the label's farthest voxel

The reference is the label's reconstructed surface as triangles (:func:`heoslice.volume.surface.label_surface`),
and r, f(r) and the halftone are the mesh route's own: :class:`heoslice.material.field.MaterialField` (the
``field`` interior) and :func:`heoslice.grading.pixel_mix.fraction_planes`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError
from heoslice.material import Material, table_material
from heoslice.material.design import Design, ReferenceRecord
from heoslice.material.field import MaterialField
from heoslice.material.functions import DistributionFunction, make_function
from heoslice.volume import Label, Volume
from heoslice.volume.model import labels_named

#: The keys a [grade] entry may have.
GRADE_KEYS = {"to", "toward", "function", "alpha", "beta", "lam", "periods", "expression", "range"}


@dataclass(frozen=True)
class GradeSetting:
    """One [grade] entry as written: the graded label's key, M2's name, the reference label's key (None: the
    label's own boundary), f(r) and the range (mm; None: 0 .. the farthest voxel)."""

    label: str
    target: Material
    toward: str | None
    function: DistributionFunction
    r_range: tuple[float, float] | None

    def record(self) -> dict:
        return {"to": self.target.name, "toward": self.toward, "function": self.function.describe(),
                "range_mm": None if self.r_range is None else list(self.r_range)}


def read_grades(data: dict, table: dict[str, Material], where: str) -> tuple[GradeSetting, ...]:
    """The [grade] entries of a parsed materials file (``data``: its ``grade`` table); InputError naming ``where``."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: [grade.LABEL] tables: to = MATERIAL, toward = LABEL, function, range")
    out = []
    for key, entry in data.items():
        name = f"{where}.{key}"
        if not isinstance(entry, dict) or not isinstance(entry.get("to"), str) or set(entry) - GRADE_KEYS:
            raise InputError(f"{name}: give to = MATERIAL (and toward = LABEL, function = KIND, range = [R0, R1]); "
                             f"keys: {', '.join(sorted(GRADE_KEYS))}")
        if table_material(entry["to"], table) is None:
            raise InputError(f"{name}: unknown material {entry['to']!r} (materials: {', '.join(table)})")
        toward = entry.get("toward")
        if toward is not None and not isinstance(toward, (str, int)):
            raise InputError(f"{name}: toward must be a label value or name, got {toward!r}")
        try:
            function = make_function(str(entry.get("function", "linear")),
                                     *(entry.get(k) for k in ("alpha", "beta", "lam", "periods", "expression")))
        except InputError as err:
            raise InputError(f"{name}: {err}") from None
        r_range = entry.get("range")
        if r_range is not None:
            if not (isinstance(r_range, list) and len(r_range) == 2 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in r_range)
                    and np.isfinite(r_range).all() and r_range[1] > r_range[0] >= 0):
                raise InputError(f"{name}: range must be [R0, R1] mm with 0 <= R0 < R1, got {r_range!r}")
            r_range = (float(r_range[0]), float(r_range[1]))
        out.append(GradeSetting(str(key), table_material(entry["to"], table), None if toward is None else str(toward),
                                function, r_range))
    return tuple(out)


@dataclass(frozen=True)
class LabelGrade:
    """A graded label resolved against the volume: its index among the printed labels, the reference label,
    M1 and M2, and the setting as written."""

    index: int
    reference: Label
    start: Material
    target: Material
    setting: GradeSetting


def resolve_grades(settings: tuple[GradeSetting, ...], volume: Volume, printed: tuple[Label, ...],
                   start_of: list[Material]) -> tuple[LabelGrade, ...]:
    """Each [grade] entry's labels among the ``printed`` labels (with materials ``start_of``) and their reference
    label among the volume's. A key may name several labels (a name shared by segments, a value on several
    layers): each is graded from its own boundary, or from the one label ``toward`` names. InputError for a key
    naming no label, a label not printed or graded twice, and a ``toward`` naming no label or several (r needs
    one surface)."""
    out, seen = [], set()
    for setting in settings:
        found = labels_named(setting.label, printed)
        if not found:
            known = labels_named(setting.label, volume.labels)
            raise InputError(f"{volume.source}: [grade] {setting.label}: " + (
                "the label is not printed (list it in [labels])" if known else "no such label in the file"))
        toward = None
        if setting.toward is not None:
            named = labels_named(setting.toward, volume.labels)
            if len(named) != 1:
                several = ", ".join(volume.labels[index].describe() for index in named)
                raise InputError(f"{volume.source}: [grade] {setting.label}: toward {setting.toward}: " + (
                    f"names {len(named)} labels ({several}); name one (by value or name)" if named else
                    "no such label in the file"))
            toward = volume.labels[named[0]]
        for index in found:
            if index in seen:
                raise InputError(f"{volume.source}: [grade]: label {printed[index].describe()} is graded twice")
            seen.add(index)
            out.append(LabelGrade(index, printed[index] if toward is None else toward, start_of[index],
                                  setting.target, setting))
    return tuple(out)


def grade_field(grade: LabelGrade, vertices: np.ndarray, faces: np.ndarray, voxel_mm: np.ndarray) -> MaterialField:
    """The graded label's material field: r the distance to the reference surface (``vertices`` (n, 3) printer
    mm, ``faces`` (m, 3)) over the setting's range, or 0 .. the farthest of the label's voxel centres
    (``voxel_mm`` (k, 3) printer mm) where none is given."""
    from heoslice.material.references import Reference, reference_distance
    from heoslice.material.surface import build_surface_index

    reference = Reference("surface", surface=build_surface_index(vertices, faces))
    setting = grade.setting
    r_range, range_from = setting.r_range, "range"
    if r_range is None:
        farthest = float(reference_distance(reference, voxel_mm).max()) if len(voxel_mm) else 0.0
        r_range, range_from = (0.0, max(farthest, 1e-3)), "max"
    recorded = ReferenceRecord("surface", surface=f"label {grade.reference.describe()}")
    design = Design(grade.start, grade.target, recorded, setting.function, r_range, range_from)
    return MaterialField(design, reference)
