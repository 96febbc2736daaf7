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
    masks (indices in mask order) hold the start and the target, and the r (h, w) of the last layer evaluated
    (the band source reads the r the design source computed; -1 off the solid's box)."""

    directory: Path
    manifest: dict
    field: MaterialField
    grid: Grid
    start: int
    target: int
    last: tuple[int, np.ndarray] | None = None

    def design(self, index: int) -> np.ndarray:
        """Layer ``index``'s designed mix (masks, h, w) float32: 1 - f(r) on the start's mask, f(r) on the
        target's, 0 elsewhere: f at each solid pixel as the slice halftoned it (anything outside the solid)."""
        solid = read_layer_mask(self.directory, self.manifest, index)
        z = float(self.manifest["layers"][index]["z_mm"])
        (r0, r1, c0, c1), r = self.field.layer_distance(np.packbits(solid, axis=-1), self.grid, z)
        full = np.full(solid.shape, -1.0)
        full[r0:r1, c0:c1] = np.broadcast_to(r, (r1 - r0, c1 - c0))
        self.last = (index, full)
        f = self.field.fraction(np.clip(full, 0.0, 1.0).astype(np.float32))
        mix = np.zeros((len(widest_masks(self.manifest)), *solid.shape), dtype=np.float32)
        mix[self.start] = 1.0 - f
        mix[self.target] += f
        return mix

    def bands(self, index: int, designed: np.ndarray | None) -> np.ndarray:
        """Layer ``index``'s band of r per pixel (h, w) int: 0..R_BANDS-1 (r = 1 in the last), -1 off the solid's
        box."""
        if self.last is None or self.last[0] != index:
            self.design(index)
        r = self.last[1]
        return np.where(r < 0, -1, np.minimum((r * R_BANDS).astype(np.int64), R_BANDS - 1))


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
