"""The design a field-interior stack records, evaluated again for ``verify``: each layer's designed share of the
target per pixel and each pixel's band of r, from the manifest's ``grading.design`` through the same
:class:`heoslice.material.field.MaterialField` code ``slice`` halftoned (one source of truth for f(r)).

A stack sliced with ``--interior field`` from a model ``heoslice color`` designed records the design (materials,
reference, f, the r normalisation, already at the slice's ``--scale``), the pixel grid and every layer's z; the
layer's solid mask read back gives the same box and the same r at every solid pixel centre that the slice used.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from heoslice.errors import MalformedDesign
from heoslice.stack.manifest import source_scale, widest_masks
from heoslice.stack.packed import Bits
from heoslice.stack.read import read_layer_mask
from heoslice.stack.report import CodedDesign, LayerTally, coded_tally, counted_tally, window_grid

if TYPE_CHECKING:
    from heoslice.layers.rasterising import Grid
    from heoslice.material.field import MaterialField

#: Bands of r the recorded design is compared over (10: r in [0, 0.1), ..., [0.9, 1]).
R_BANDS = 10


def recorded_design(manifest: dict, source: str = "stack") -> dict | None:
    """The ``grading.design`` record of a stack whose solid got the design's field (``grading.interior`` is
    ``field``), or None for any other stack; MalformedDesign for a field stack without one (its design lost, so
    what it delivers cannot be compared)."""
    grading = manifest.get("grading")
    if not isinstance(grading, dict) or grading.get("interior") != "field":
        return None
    design = grading.get("design")
    if not isinstance(design, dict):
        raise MalformedDesign(f"{source}: a field-interior stack without its design record (grading.design)")
    return design


@dataclass(eq=False)
class RecordedField:
    """A stack's recorded design ready to compare: the stack (folder, manifest), the field, its pixel grid, and
    which masks (indices in mask order) hold the start and the target. A layer's design is a code per solid pixel,
    r's step k of r = k / R_STEPS (:meth:`coded`), read through tables of f and of r's band per step: the steps a
    surface reference's slice halftoned, and a closed form's r rounded to the nearest step, as its slice rounds it
    (a tie at half a step aside)."""

    directory: Path
    manifest: dict
    field: MaterialField
    grid: Grid
    start: int
    target: int

    @cached_property
    def tables(self) -> tuple[np.ndarray, np.ndarray]:
        """(f (R_STEPS + 1,) float32, the field's :attr:`MaterialField.fraction_table` in the precision the slice
        dithers it (an expression's or a constant's table is float64); the band of r (R_STEPS + 1,) int64: min(r
        R_BANDS, R_BANDS - 1) in float32, r = k / R_STEPS)."""
        from heoslice.material.field import R_STEPS

        r = np.arange(R_STEPS + 1, dtype=np.float32) / np.float32(R_STEPS)
        return (self.field.fraction_table.astype(np.float32),
                np.minimum(r * np.float32(R_BANDS), R_BANDS - 1).astype(np.int64))

    def coded(self, index: int, packed: np.ndarray) -> CodedDesign:
        """Layer ``index``'s design over its solid pixels (``packed``: (h, ceil(w / 8)) uint8, MSB first), as the
        compiled tally reads it (:class:`heoslice.stack.report.CodedDesign`)."""
        from heoslice.material.field import R_STEPS

        z = float(self.manifest["layers"][index]["z_mm"])
        shares, bands = self.tables
        empty = CodedDesign((0, 0, 0, 0), np.zeros((0, 0), np.uint16), shares, bands, R_BANDS, self.start, self.target)
        if not packed.any():
            return empty
        if self.field.reference.kind == "surface":
            box, codes = self.field.layer_steps(packed, self.grid, z)
        else:
            box, r = self.field.layer_distance(packed, self.grid, z)
            shape = (box[1] - box[0], box[3] - box[2])
            codes = np.rint(np.clip(np.broadcast_to(r, shape), 0.0, 1.0) * R_STEPS).astype(np.uint16)
        return replace(empty, box=box, codes=np.ascontiguousarray(codes, dtype=np.uint16))

    def design(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Layer ``index``'s designed mix (masks, h, w) float32 (1 - f on the start's mask, f on the target's, 0
        elsewhere) and band of r per pixel (h, w) int8 (-1 off the solid), from :meth:`coded`: what the compiled
        tally compares, as arrays (for a script or a test; ``verify`` does not make them)."""
        solid = read_layer_mask(self.directory, self.manifest, index)
        coded = self.coded(index, np.packbits(solid, axis=-1))
        (r0, r1, c0, c1), shares, bands = coded.box, *self.tables
        codes = np.minimum(coded.codes, len(shares) - 1)
        mix = np.zeros((len(widest_masks(self.manifest)), *solid.shape), np.float32)
        mix[self.target, r0:r1, c0:c1] = shares[codes]
        mix[self.start, r0:r1, c0:c1] = np.float32(1.0) - shares[codes]
        mix *= solid
        labels = np.full(solid.shape, -1, np.int8)
        labels[r0:r1, c0:c1] = bands[codes]
        labels[~solid] = -1
        return mix, labels

    def tally(self, index: int, bits: list[Bits]) -> LayerTally:
        """Layer ``index``'s tally against the design, from the bits of its files that verify checked (its solid
        pixels', then its droplet masks'; its counts are then its manifest entry's): :func:`coded_tally`."""
        tally = coded_tally(index, bits, self.coded(index, bits[0].rows), window_grid(self.manifest),
                            self.grid.width, counted_tally(self.manifest, index))
        worst = tally.worst
        if worst is not None and worst.material == self.start and len(bits) == 3:
            # two masks partition the solid: the start's miss is the target's, told as the target's share (the
            # one the bands give) rather than whichever of the two rounding put first
            worst = replace(worst, material=self.target, designed=1.0 - worst.designed,
                            delivered=1.0 - worst.delivered)
        return replace(tally, worst=worst)


def field_comparison(directory: Path, manifest: dict) -> RecordedField | None:
    """The recorded design of a verified field-interior stack as design and band sources (None for a stack
    without one, or without droplet masks). MalformedDesign (one line) for a record that cannot be read, is
    missing or names a material the stack has no droplet mask of; InputError when the design cannot be evaluated:
    its surface reference missing or changed since the model was coloured."""
    record = recorded_design(manifest, str(directory))
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
    if not names:  # an RGBA preview of the design: no droplets to compare (verify refuses to print it)
        return None
    missing = [m.name for m in (design.start, design.target) if m.name not in names]
    if missing:
        raise MalformedDesign(f"{directory}: the design record's material(s) {', '.join(missing)} have no droplet "
                              f"mask (masks: {', '.join(names) or 'none'})")
    image = manifest["image"]
    (px, py), (x_left, y_top) = manifest["pixel_size_mm"], image["origin_mm"]
    grid = Grid(int(image["width"]), int(image["height"]), float(x_left), float(y_top), float(px), float(py))
    return RecordedField(directory, manifest, material_field(design, directory), grid,
                         names.index(design.start.name), names.index(design.target.name))
