"""The volume rule of ``verify --mesh``: how far a stack's volume may be from its mesh's, and what a miss means."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.mesh.load import Mesh
from heoslice.mesh.topology import edge_use_counts
from heoslice.mesh.volume import solid_volume_mm3


@dataclass(frozen=True)
class VolumeCheck:
    """A stack's volume against its mesh's (mm^3): the relative difference (None when the mesh has no volume)
    and, beyond the tolerance, the line to report as a problem or as a warning."""

    mesh_volume_mm3: float
    watertight: bool
    relative: float | None
    problem: str | None
    warning: str | None


def volume_check(mesh: Mesh, stack_volume_mm3: float, tolerance: float) -> VolumeCheck:
    """Compare a stack's volume with the solid volume of its (scaled) mesh, as ``info`` reports it.

    A difference above ``tolerance`` (relative) is a problem for a watertight mesh whose
    shells could be united, and only a warning otherwise (an open mesh has no
    well-defined volume; overlapping shells not united may count twice).
    """
    watertight = bool(np.all(edge_use_counts(mesh.faces) == 2))
    mesh_volume, exact = solid_volume_mm3(mesh)
    relative = (stack_volume_mm3 - mesh_volume) / abs(mesh_volume) if mesh_volume else float("inf")
    problem = warning = None
    if not abs(relative) <= tolerance:
        line = (f"stack volume {stack_volume_mm3:.6g} mm^3 differs from the mesh volume {mesh_volume:.6g} mm^3 "
                f"by {100 * relative:+.2f} % (tolerance {100 * tolerance:g} %)")
        if watertight and exact:
            problem = line
        elif not watertight:
            warning = f"{line}; the mesh is not watertight, so its volume is only approximate"
        else:
            warning = f"{line}; its shells could not be united, so overlaps may count twice"
    return VolumeCheck(mesh_volume_mm3=mesh_volume, watertight=watertight,
                       relative=relative if np.isfinite(relative) else None, problem=problem, warning=warning)
