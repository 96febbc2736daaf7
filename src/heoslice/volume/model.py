"""The loaded volume: one typed object for every reader (NIfTI, NRRD, a structure folder, DICOM), and the
checks every reader applies to what it read (sizes, affine, voxel size, NaN voxels).

A volume's voxel (i, j, k) sits at ``affine @ (i, j, k, 1)`` in millimetres of its patient space: RAS
(NIfTI's: +x toward the patient's right, +y anterior, +z superior) or LPS (DICOM's and NRRD's: +x left,
+y posterior, +z superior; the same point has x and y negated). Label maps keep their integer values;
a label map of overlapping structures is several layers (a Slicer ``.seg.nrrd`` of overlapping segments,
a folder of one file per structure), each label naming its layer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import InputError

#: Patient spaces: the letters name where +x, +y, +z point (Right, Anterior, Superior; Left, Posterior, Superior).
SPACES = ("RAS", "LPS")
KINDS = ("labels", "intensity")
#: Largest voxel array read (uncompressed bytes), checked from the header before any data is read: a
#: 1024^3 CT of int16 is 2 GiB; a gzip whose header declares more is refused (a decompression bomb).
MAX_VOLUME_BYTES = 3 << 30
#: Most voxels, and most labels one label map may carry.
MAX_VOXELS = 1 << 30
MAX_LABELS = 4096
#: Voxel sizes accepted, mm (a micro-CT's 1 micrometre to a 100 mm slab).
MIN_VOXEL_MM, MAX_VOXEL_MM = 1e-3, 100.0
#: Largest distance of any voxel from the space's origin, mm (10 m).
MAX_EXTENT_MM = 1e4
#: Tolerance on the cosine between two voxel axes for them to count as orthogonal.
ORTHOGONAL_COSINE = 1e-3


@dataclass(frozen=True)
class Label:
    """One label of a label map: its value in its layer's voxels, its name and display colour ((r, g, b)
    0..255) where the file gives them (None otherwise), and its layer (0 unless the map has several)."""

    value: int
    name: str | None = None
    color: tuple[int, int, int] | None = None
    layer: int = 0

    def describe(self) -> str:
        """'5 liver' or '5' for a label without a name."""
        return f"{self.value} {self.name}" if self.name else str(self.value)


@dataclass(frozen=True)
class Volume:
    """A voxel volume in patient space.

    data: (i, j, k) array, or (layers, i, j, k) for a label map of several layers (overlapping structures);
    affine: (4, 4) float64 mapping voxel indices (i, j, k, 1) to millimetres in ``space`` ("RAS" or "LPS");
    kind: "labels" (integer label values, 0 = background) or "intensity" (e.g. CT in Hounsfield units);
    labels: the labels (value, name, colour, layer) a label map holds, () for an intensity volume;
    source, sha256: the file (or folder) read and a digest of its content; warnings: notes for the user;
    kind_guessed: the kind was guessed from the voxels (not forced, not implied by the format); names_only: the
    label values are not the file's own (a folder's structures, numbered by file order), so only names select.
    """

    data: np.ndarray
    affine: np.ndarray
    space: str
    kind: str
    labels: tuple[Label, ...]
    source: Path
    sha256: str
    warnings: tuple[str, ...] = ()
    kind_guessed: bool = False
    names_only: bool = False

    @property
    def shape(self) -> tuple[int, int, int]:
        """The spatial shape (i, j, k)."""
        return tuple(int(n) for n in self.data.shape[-3:])

    @property
    def layer_count(self) -> int:
        return 1 if self.data.ndim == 3 else int(self.data.shape[0])

    @property
    def voxel_size_mm(self) -> np.ndarray:
        """(3,) float, mm: the length of each voxel axis."""
        return np.linalg.norm(self.affine[:3, :3], axis=0)

    @property
    def voxel_volume_mm3(self) -> float:
        return float(abs(np.linalg.det(self.affine[:3, :3])))

    def layer(self, index: int) -> np.ndarray:
        """The (i, j, k) array of one layer."""
        return self.data if self.data.ndim == 3 else self.data[index]

    def label_mask(self, label: Label) -> np.ndarray:
        """(i, j, k) bool: the voxels of ``label``."""
        return self.layer(label.layer) == label.value

    def ras_affine(self) -> np.ndarray:
        """(4, 4) float: the affine to RAS millimetres (LPS x and y negated)."""
        return self.affine if self.space == "RAS" else np.diag([-1.0, -1.0, 1.0, 1.0]) @ self.affine


def check_declared_size(path: Path, shape, itemsize: int) -> None:
    """Refuse, from a header and before any data is read, a volume declaring more voxels or bytes than the limits
    (a decompression bomb declares what it would inflate to)."""
    dims = [int(n) for n in shape]
    if any(n < 1 for n in dims):
        raise InputError(f"{path}: header declares an empty volume of shape {tuple(dims)}")
    voxels = int(np.prod(np.array(dims, dtype=object)))
    if voxels > MAX_VOXELS or voxels * itemsize > MAX_VOLUME_BYTES:
        raise InputError(f"{path}: header declares {voxels} voxels ({voxels * itemsize} bytes), more than the "
                         f"{MAX_VOLUME_BYTES} bytes heoslice reads")


def check_affine(path: Path, affine: np.ndarray, shape) -> np.ndarray:
    """The (4, 4) float64 affine after refusing one that is not finite, singular, non-orthogonal (sheared), with
    voxels outside MIN_VOXEL_MM..MAX_VOXEL_MM, or reaching beyond MAX_EXTENT_MM; InputError naming the file."""
    affine = np.asarray(affine, dtype=np.float64)
    if affine.shape != (4, 4) or not np.all(np.isfinite(affine)):
        raise InputError(f"{path}: the voxel-to-patient transform is not a finite 4 x 4 matrix")
    axes = affine[:3, :3]
    sizes = np.linalg.norm(axes, axis=0)
    if not np.all(sizes > 0) or abs(np.linalg.det(axes)) <= 1e-12 * float(np.prod(np.maximum(sizes, 1e-300))):
        raise InputError(f"{path}: the voxel-to-patient transform is singular "
                         f"(voxel axes {np.round(sizes, 6).tolist()} mm)")
    if np.any(sizes < MIN_VOXEL_MM) or np.any(sizes > MAX_VOXEL_MM):
        raise InputError(f"{path}: voxel size {np.round(sizes, 6).tolist()} mm is outside the "
                         f"{MIN_VOXEL_MM:g} .. {MAX_VOXEL_MM:g} mm heoslice accepts")
    unit = axes / sizes
    cosines = np.abs(unit.T @ unit - np.eye(3))
    if cosines.max() > ORTHOGONAL_COSINE:
        raise InputError(f"{path}: the voxel axes are not orthogonal (a sheared volume, cosine "
                         f"{cosines.max():.3g} between two axes); resample it to an orthogonal grid")
    corners = np.array([[i, j, k, 1.0] for i in (0, shape[0] - 1) for j in (0, shape[1] - 1)
                        for k in (0, shape[2] - 1)]) @ affine.T
    if np.abs(corners[:, :3]).max() > MAX_EXTENT_MM:
        raise InputError(f"{path}: voxels reach {np.abs(corners[:, :3]).max():g} mm from the origin, beyond "
                         f"the {MAX_EXTENT_MM:g} mm heoslice accepts")
    return affine


def check_values(path: Path, data: np.ndarray) -> None:
    """Refuse NaN or infinite voxels (one line, with how many)."""
    if data.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(data)))
        if bad:
            raise InputError(f"{path}: {bad} voxel(s) are NaN or infinite")


def label_values(data: np.ndarray) -> np.ndarray:
    """The sorted non-zero values of a label array, (n,) int64."""
    return np.unique(data[data != 0]).astype(np.int64) if data.size else np.zeros(0, np.int64)


def make_labels(path: Path, data: np.ndarray, known: dict[int, Label] | None = None) -> tuple[Label, ...]:
    """The labels of a one-layer label map: every non-zero value, with the name and colour ``known`` gives it."""
    values = label_values(data)
    if len(values) > MAX_LABELS:
        raise InputError(f"{path}: {len(values)} distinct labels, more than the {MAX_LABELS} of a label map "
                         "(is it an intensity volume? say --as intensity)")
    known = known or {}
    return tuple(known.get(int(value), Label(int(value))) for value in values)


def as_label_array(path: Path, data: np.ndarray) -> np.ndarray:
    """``data`` as an integer label array: integers unchanged, float voxels that are all whole numbers cast;
    anything else refused."""
    if data.dtype.kind == "b":
        return data.astype(np.uint8)
    if data.dtype.kind == "u":
        return data
    if data.dtype.kind == "f":
        check_values(path, data)
    if data.dtype.kind in "if" and data.size and data.min() < 0:
        raise InputError(f"{path}: {int(np.count_nonzero(data < 0))} voxel(s) of negative value (e.g. "
                         f"{data.min():g}): label values are 0 (background) or positive, so not a label map "
                         "(an intensity volume: say --as intensity)")
    if data.dtype.kind == "i":
        return data
    if data.dtype.kind == "f" and np.all(data == np.round(data)) and np.abs(data).max(initial=0) < 2**31:
        return data.astype(np.int32)
    raise InputError(f"{path}: voxels are not whole numbers, so not a label map (an intensity volume: say --as "
                     "intensity)")


def is_number_key(key) -> bool:
    """Whether a [labels] key is a label value (a whole number) rather than a name."""
    return str(key).strip().lstrip("-").isdigit()


def check_label_keys(volume: Volume, keys, where: str) -> None:
    """Refuse label-value keys (numbers) for a volume whose labels only names select (a folder of structure
    files numbers them by file order, so a number would pick whichever file sorts there)."""
    if not volume.names_only:
        return
    numbers = [str(key) for key in keys if is_number_key(key)]
    if numbers:
        example = next((label.name for label in volume.labels if label.name), "liver")
        raise InputError(f"{where}: {numbers[0]}: {volume.source} is a folder of structure files, whose labels have "
                         f"no values of their own; name the structure instead (e.g. {example})")


def labels_named(key: str, labels: tuple[Label, ...]) -> list[int]:
    """Indices of the labels a [labels] key names: a whole number is a label value, anything else a segment
    or structure name (case ignored)."""
    text = str(key).strip()
    if is_number_key(text):
        return [index for index, label in enumerate(labels) if label.value == int(text)]
    return [index for index, label in enumerate(labels) if label.name and label.name.lower() == text.lower()]
