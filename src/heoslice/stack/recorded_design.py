"""The design a field-interior stack records, evaluated again for ``verify``: each layer's designed share of the
target per pixel and each pixel's band of r, from the manifest's ``grading.design`` through the same
:class:`heoslice.material.field.MaterialField` code ``slice`` halftoned (one source of truth for f(r)).

A stack sliced with ``--interior field`` from a model ``heoslice color`` designed records the design (materials,
reference, f, the r normalisation, already at the slice's ``--scale``), the pixel grid and every layer's z; the
layer's solid mask read back gives the same box and the same r at every solid pixel centre that the slice used.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from heoslice.errors import InputError
from heoslice.stack.manifest import source_scale, widest_masks
from heoslice.stack.read import read_layer_mask

if TYPE_CHECKING:
    from heoslice.layers.rasterising import Grid
    from heoslice.material.field import MaterialField

#: Bands of r the recorded design is compared over (10: r in [0, 0.1), ..., [0.9, 1]).
R_BANDS = 10


def recorded_design(manifest: dict) -> dict | None:
    """The ``grading.design`` record of a stack whose solid got the design's field (``grading.interior`` is
    ``field``), or None for any other stack."""
    grading = manifest.get("grading")
    if not isinstance(grading, dict) or grading.get("interior") != "field":
        return None
    design = grading.get("design")
    return design if isinstance(design, dict) else None


@dataclass(eq=False)
class RecordedField:
    """A stack's recorded design ready to compare: the stack (folder, manifest), the field, its pixel grid, which
    masks (indices in mask order) hold the start and the target, and the last layer evaluated (its index, the
    solid's box (r0, r1, c0, c1) and r over it, (r1 - r0, c1 - c0) float32, which the band source reads). The
    layer-size arrays it returns (``mix``, ``labels``) are kept and refilled layer after layer (:func:`_refilled`):
    a large array made afresh comes back as newly mapped pages every layer (benchmarks/README.md)."""

    directory: Path
    manifest: dict
    field: MaterialField
    grid: Grid
    start: int
    target: int
    last: tuple[int, tuple[int, int, int, int], np.ndarray] | None = None
    mix: np.ndarray | None = None
    labels: np.ndarray | None = None

    def _box_r(self, solid: np.ndarray, z: float) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
        """The solid's box, and r and f(r) over it (float32): a surface reference's from the slice's own
        per-voxel steps of r (:meth:`MaterialField.layer_steps`) and its table of f, as the slice halftoned them;
        another's from its closed form."""
        packed = np.packbits(solid, axis=-1)
        if self.field.reference.kind == "surface":
            from heoslice.material.field import R_STEPS

            box, steps = self.field.layer_steps(packed, self.grid, z)
            steps = np.minimum(steps, R_STEPS)  # a step off the solid may be anything
            return box, steps.astype(np.float32) / np.float32(R_STEPS), np.take(self.field.fraction_table, steps)
        box, r = self.field.layer_distance(packed, self.grid, z)
        r = np.broadcast_to(np.asarray(r, dtype=np.float32), (box[1] - box[0], box[3] - box[2]))
        return box, r, self.field.fraction(np.clip(r, 0.0, 1.0))

    def design(self, index: int) -> np.ndarray:
        """Layer ``index``'s designed mix (masks, h, w) float32: 1 - f(r) on the start's mask, f(r) on the
        target's, over the solid's box (0 elsewhere): f at each solid pixel as the slice halftoned it. Valid until
        the next layer's."""
        solid = read_layer_mask(self.directory, self.manifest, index)
        (r0, r1, c0, c1), r, f = self._box_r(solid, float(self.manifest["layers"][index]["z_mm"]))
        self.last = (index, (r0, r1, c0, c1), r)
        mix = self.mix = _refilled(self.mix, (len(widest_masks(self.manifest)), *solid.shape), np.float32, 0.0)
        mix[self.target, r0:r1, c0:c1] = f
        np.subtract(np.float32(1.0), mix[self.target, r0:r1, c0:c1], out=mix[self.start, r0:r1, c0:c1])
        return mix

    def bands(self, index: int, designed: np.ndarray | None) -> np.ndarray:
        """Layer ``index``'s band of r per pixel (h, w) int8: 0..R_BANDS-1 (r = 1 in the last), -1 off the solid's
        box. Valid until the next layer's."""
        if self.last is None or self.last[0] != index:
            self.design(index)
        _, (r0, r1, c0, c1), r = self.last
        shape = (int(self.manifest["image"]["height"]), int(self.manifest["image"]["width"]))
        labels = self.labels = _refilled(self.labels, shape, np.int8, -1)
        labels[r0:r1, c0:c1] = np.minimum(np.clip(r, 0.0, 1.0) * R_BANDS, R_BANDS - 1).astype(np.int8)
        return labels


def _refilled(array: np.ndarray | None, shape: tuple[int, ...], dtype, fill) -> np.ndarray:
    """``array`` filled with ``fill``, or a new one of this shape and dtype when it is None or another."""
    if array is None or array.shape != shape or array.dtype != dtype:
        array = np.empty(shape, dtype=dtype)
    array.fill(fill)
    return array


def field_comparison(directory: Path, manifest: dict) -> RecordedField | None:
    """The recorded design of a verified field-interior stack as design and band sources (None for a stack
    without one). InputError (one line) when the design cannot be evaluated: a malformed record, a mask of the
    design's materials missing, or a surface reference missing or changed since the model was coloured."""
    record = recorded_design(manifest)
    if record is None:
        return None
    from heoslice.layers.rasterising import Grid  # the design's machinery, loaded only for a stack that has one
    from heoslice.material.design import Design
    from heoslice.material.field import material_field

    design = Design.from_record(record, str(directory))
    if design.reference.kind == "surface" and "scale" not in record["reference"]:
        # a record from before the surface's scale was recorded: the slice's --scale alone
        design = replace(design, reference=replace(design.reference, surface_scale=source_scale(manifest)))
    names = [str(mask.get("material")) for mask in widest_masks(manifest)]
    missing = [m.name for m in (design.start, design.target) if m.name not in names]
    if missing:
        raise InputError(f"{directory}: the design's material(s) {', '.join(missing)} have no droplet mask "
                         f"(masks: {', '.join(names) or 'none'})")
    image = manifest["image"]
    (px, py), (x_left, y_top) = manifest["pixel_size_mm"], image["origin_mm"]
    grid = Grid(int(image["width"]), int(image["height"]), float(x_left), float(y_top), float(px), float(py))
    return RecordedField(directory, manifest, material_field(design, directory), grid,
                         names.index(design.start.name), names.index(design.target.name))
