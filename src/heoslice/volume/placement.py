"""Where a volume's voxels go on the printer: the printer's frame in the scan's patient space.

The printer's x, y, z are the scan's RAS millimetres turned so that printer +z is the anatomical direction
``up`` (default "S": superior, the scan's +z; LPS volumes are first taken to RAS by negating x and y). A mesh
in the same RAS millimetres, sliced as it is, lands on the same pixels. Slicing resamples along the
printer's axes, so each voxel axis must run along one printer axis (an axis-aligned scan, as CT and most
segmentations are); an oblique volume is refused with the advice to resample it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError
from heoslice.volume.model import Volume

#: Anatomical direction that becomes printer +z -> the rotation (3, 3) taking RAS to printer x, y, z (each a
#: proper rotation: a print is never mirrored).
UP_AXES = {
    "S": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "I": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "A": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "P": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "R": ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
    "L": ((0, 0, 1), (0, 1, 0), (-1, 0, 0)),
}
#: Largest off-axis part of a voxel axis (relative) still taken as axis-aligned.
ALIGNED_TOLERANCE = 1e-4


@dataclass(frozen=True)
class Placement:
    """A volume on the printer's axes.

    printer_from_scan: (4, 4) float taking the file's space (RAS or LPS, mm) to printer mm; ``axes``: for
    printer x, y, z the voxel axis (0, 1, 2) that runs along it; ``steps``: (3,) float, the printer mm one voxel
    step along that axis moves (negative: the voxel axis runs against the printer's); ``origin``: (3,) float,
    printer mm of voxel (0, 0, 0)'s centre.
    """

    up: str
    printer_from_scan: np.ndarray
    axes: tuple[int, int, int]
    steps: np.ndarray
    origin: np.ndarray

    def orient(self, array: np.ndarray) -> np.ndarray:
        """An (i, j, k) voxel array as (z, y, x) along the printer's axes, each index rising with its printer
        coordinate (a view: transposed and flipped, not copied)."""
        view = np.transpose(array, (self.axes[2], self.axes[1], self.axes[0]))
        flips = tuple(axis for axis, step in zip((0, 1, 2), self.steps[::-1]) if step < 0)
        return np.flip(view, axis=flips) if flips else view

    def oriented_origin(self, shape: tuple[int, int, int]) -> np.ndarray:
        """(3,) float: printer (z, y, x) mm of element (0, 0, 0) of :meth:`orient`'s array of a volume of ``shape``."""
        counts = np.array([shape[axis] for axis in self.axes], dtype=np.float64)
        low = self.origin + np.where(self.steps < 0, self.steps * (counts - 1), 0.0)
        return low[::-1]

    @property
    def spacing(self) -> np.ndarray:
        """(3,) float: voxel size along printer z, y, x (mm)."""
        return np.abs(self.steps)[::-1]

    def record(self, space: str, corner_mm) -> dict:
        """The manifest's ``placement`` object: the scan's space, the up direction, the 4 x 4 matrix from the
        scan's space to printer mm, and the print's origin in the scan's space: where the first layer image's
        top-left corner (``corner_mm``, printer x, y, z: the image origin at the stack's lowest z) is."""
        corner = np.linalg.inv(self.printer_from_scan) @ np.array([*corner_mm, 1.0])
        return {"space": space, "up": self.up,
                "printer_from_scan": [[float(v) for v in row] for row in self.printer_from_scan],
                "print_origin_in_scan_mm": [float(v) for v in corner[:3]]}


def printer_from_scan(space: str, up: str = "S") -> np.ndarray:
    """(4, 4) float: the file's space (RAS or LPS, mm) to printer mm with anatomical ``up`` as printer +z."""
    if up not in UP_AXES:
        raise InputError(f"up: {up!r} is not an anatomical direction ({', '.join(UP_AXES)})")
    turn = np.eye(4)
    turn[:3, :3] = np.array(UP_AXES[up], dtype=np.float64)
    to_ras = np.eye(4) if space == "RAS" else np.diag([-1.0, -1.0, 1.0, 1.0])
    return turn @ to_ras


def place(volume: Volume, up: str = "S") -> Placement:
    """The :class:`Placement` of ``volume`` with ``up`` as printer +z; InputError for an oblique volume."""
    matrix = printer_from_scan(volume.space, up)
    voxel_to_printer = matrix @ volume.affine
    axes3 = voxel_to_printer[:3, :3]
    dominant = np.argmax(np.abs(axes3), axis=0)  # the printer axis each voxel axis runs along
    off_axis = np.abs(axes3).sum(axis=0) - np.abs(axes3).max(axis=0)
    if len(set(dominant.tolist())) != 3 or np.any(off_axis > ALIGNED_TOLERANCE * np.abs(axes3).max(axis=0)):
        raise InputError(f"{volume.source}: an oblique volume (its voxel axes are not along the patient's axes); "
                         "resample it to an axis-aligned grid first (e.g. 3D Slicer's Resample Scalar Volume)")
    axes = tuple(int(np.flatnonzero(dominant == printer)[0]) for printer in range(3))
    steps = np.array([axes3[printer, axes[printer]] for printer in range(3)])
    return Placement(up, matrix, axes, steps, voxel_to_printer[:3, 3].copy())
