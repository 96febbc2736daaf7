"""Profile families of a layer (an outer ring with the holes directly inside it) and how each is graded (eq. 8-10)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.grading.spec import RegionSpec, band_count


@dataclass(frozen=True)
class Family:
    """One profile family of a layer: loop indices (within the layer) of its outer ring and holes.

    ``nested`` is True when the outer ring lies inside another family's solid (a shell
    inside a shell, e.g. a lesion in an organ): its region keeps its own material.
    ``depth`` is the number of outer rings around it (families are painted outermost first).
    """

    outer: int
    holes: tuple[int, ...]
    nested: bool
    depth: int


def layer_families(area: np.ndarray, parent: np.ndarray) -> list[Family]:
    """The families of one layer's loops (signed areas (l,), parents (l,) within the layer), outermost first.

    A hole belongs to the family of the outer ring directly around it; a hole with no
    outer ring around it (a broken mesh) is ignored.
    """
    area = np.asarray(area, dtype=np.float64)
    parent = np.asarray(parent, dtype=np.int64)
    outer = np.nonzero(area > 0)[0]
    families = []
    for loop in outer:
        holes = tuple(int(h) for h in np.nonzero((parent == loop) & (area < 0))[0])
        depth, up, nested = 0, parent[loop], bool(parent[loop] >= 0 and area[parent[loop]] > 0)
        for _ in range(len(parent)):  # at most every loop: a cycle of parents (a broken hierarchy) ends too
            if up < 0:
                break
            depth += area[up] > 0
            up = parent[up]
        families.append(Family(int(loop), holes, nested, int(depth)))
    return sorted(families, key=lambda family: (family.depth, family.outer))


@dataclass(frozen=True)
class FamilyLayout:
    """How one family is graded: ring sets (start first), N_R, band width, L_S (mm)."""

    start: tuple[int, ...]
    end: tuple[tuple[int, ...], ...]
    count: int
    length_mm: float


def family_layout(family: Family, spec: RegionSpec, inradius: float | None = None,
                  apart: float | None = None, precision_mm: float = 0.0) -> FamilyLayout:
    """Which rings start and end the grading of a family, and N_R by eq. 8.

    L_S is the target depth when given; otherwise the shortest distance between the
    starting and ending rings (``apart``, mm: :func:`rings_apart` of the outer ring and
    the holes); for a family without holes, its largest inscribed distance
    (``inradius``, mm), so that the target is reached at its deepest point; ``precision_mm`` as
    :func:`band_count`.
    """
    holes = family.holes

    def count(length: float) -> int:
        return int(spec.count) if spec.count is not None else band_count(length, spec.nozzle_mm, precision_mm)

    if spec.direction == "out" and holes:
        start, end = holes, ((family.outer,),)
    else:
        start, end = (family.outer,), tuple((hole,) for hole in holes)
    if spec.depth_mm is not None:
        return FamilyLayout(start, (), count(spec.depth_mm), float(spec.depth_mm))
    length = float((apart if holes else inradius) or 0.0)
    return FamilyLayout(start, end if holes else (), count(length), max(length, 1e-9))
