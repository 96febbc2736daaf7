"""A label map resampled layer by layer at the printer's pixels: per printed label its smooth field
(:mod:`heoslice.volume.fields`), then per layer the packed solid mask and one mask per material code
(:mod:`heoslice.volume.resample_kernels`). Memory: the fields (each on its label's box) plus one layer's
packed masks; nothing grows with the number of layers.

The rule at a pixel: it is solid where a printed label's field is positive, or where two labels' fields
both come within CRACK_VOXELS of it (the seam of two touching labels); it takes the label of highest score,
a label's score being its field plus its boost where its field is positive. A label map's labels do not
overlap, but each field may reach BAND (:mod:`heoslice.volume.fields`) past its voxels into a neighbour's,
and a thin label's field is low everywhere (at most about half a voxel plus BAND): left to the label most
inside, the organ around a one-voxel vessel or wall would take most of it. So a label map's labels are
boosted by thinness (:func:`map_boost`): a label of largest inscribed radius r < THIN_RADIUS voxels gets
THIN_RADIUS - r, so where its field and a thicker label's are both positive, it wins and keeps the volume its
own field holds; labels of THIN_RADIUS or more (an organ) keep the rule "most inside wins", and the boost
fades to 0 with thickness (no step in voxels or radius). What a thick label loses so to more boosted ones, its
level, set again outside their region by at most BAND outwards (:func:`yielding`), gives back at its other
surfaces. A higher
``priority`` of the materials file's [labels] wins over lower ones wherever both fields are positive.
Overlapping structures (a folder of one file per structure, a .seg.nrrd in layers) are boosted by rank
(:func:`heoslice.pipeline.parts.part_order`): where several claim a pixel, the higher rank wins.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from heoslice.layers.rasterising import Grid
from heoslice.volume.fields import BAND, FAR_OUTSIDE, LabelField, label_field, level_offset
from heoslice.volume.model import Label, Volume
from heoslice.volume.placement import Placement
from heoslice.volume.resample_kernels import _label_codes

#: Voxels: a label map's label of largest inscribed radius r below this is boosted by THIN_RADIUS - r. A field
#: may reach BAND (0.3 voxel) into a neighbour's voxels, a loss of about BAND / r of a label's volume left
#: unboosted: above 3 voxels, under a tenth.
THIN_RADIUS = 3.0
#: The boost of each rank of overlapping structures, and of each step of priority: above any field's range.
BOOST = np.float32(1e4)
#: Voxels: two labels whose fields both come this close to positive at a pixel make it solid (their seam).
CRACK_VOXELS = 0.25


@dataclass(frozen=True)
class LabelPrint:
    """A label map ready to resample: the printed labels' fields, material codes (1..K, (L,) uint8) and
    boosts ((L,) float32), and the oriented grid (origin: printer (z, y, x) mm of index
    (0, 0, 0); spacing: (3,) mm). ``boxes``: (L, 2, 3) int64, each label's voxel box [start, stop) (unpadded)."""

    labels: tuple[Label, ...]
    fields: tuple[LabelField, ...]
    codes: np.ndarray
    boost: np.ndarray
    origin: np.ndarray
    spacing: np.ndarray
    boxes: np.ndarray

    def bounds_mm(self) -> np.ndarray:
        """(2, 3) float, printer x, y, z mm: the printed labels' voxel boxes grown by a voxel (a reconstructed
        surface can bulge past a voxel face, never by a whole voxel)."""
        low = self.origin + (self.boxes[:, 0].min(axis=0) - 1.0) * self.spacing
        high = self.origin + self.boxes[:, 1].max(axis=0) * self.spacing
        return np.stack([low[::-1], high[::-1]])


def map_boost(fields: list[LabelField] | tuple[LabelField, ...], priorities: list[int] | None = None) -> np.ndarray:
    """(L,) float32, voxels: the boosts of a label map's labels (the module's rule): BOOST per step of
    ``priorities`` (None: all 0) above the lowest, plus THIN_RADIUS less the label's largest inscribed radius
    where it is thinner."""
    steps = np.unique(priorities, return_inverse=True)[1].reshape(-1) if priorities else np.zeros(len(fields))
    thin = np.array([max(THIN_RADIUS - field.radius, 0.0) for field in fields])
    return (BOOST * steps + thin).astype(np.float32)


def yielding(fields: list[LabelField], boost: np.ndarray) -> list[LabelField]:
    """A label map's ``fields`` with each thick one's (largest inscribed radius at least THIN_RADIUS)
    volume-preserving level set again outside the region the labels of higher ``boost`` win (their fields
    positive), from the highest boost down, by at most BAND voxels outwards: what a thin label takes back from the
    organ around it, the organ gains at its other surfaces, so it too keeps its voxel volume. A thin label does not
    yield (a line moved by a fraction of a voxel doubles its width), and the bound keeps an organ mostly wrapped by
    a thin wall (a cyst in its wall) inside the wall instead of growing through it."""
    out = list(fields)
    for index in sorted(range(len(fields)), key=lambda i: -boost[i]):
        field = out[index]
        if field.radius < THIN_RADIUS:
            continue
        taken = np.full(field.values.shape, FAR_OUTSIDE, dtype=np.float32)
        for other in np.flatnonzero(boost > boost[index]):
            low = np.maximum(out[other].start, field.start)
            high = np.minimum(out[other].stop, field.stop)
            if (high > low).all():
                here = tuple(slice(a, b) for a, b in zip(low - field.start, high - field.start))
                there = tuple(slice(a, b) for a, b in zip(low - out[other].start, high - out[other].start))
                np.maximum(taken[here], out[other].values[there], out=taken[here])
        if (taken > 0).any():
            offset = max(level_offset(field.values, field.voxels, taken), -BAND)
            values = field.values - np.float32(offset)
            out[index] = replace(field, values=values.astype(np.float32))
    return out


def label_print(volume: Volume, placement: Placement, printed: list[tuple[Label, int]], smooth: float | None = None,
                ranks: list[int] | None = None, priorities: list[int] | None = None) -> LabelPrint:
    """The :class:`LabelPrint` of ``printed`` ((label, material code 1..K) pairs, labels with voxels) of
    ``volume`` placed by ``placement``, blurred by ``smooth`` voxels (None: by each label's thickness);
    ``ranks`` (overlapping structures: 0 wins over all) gives boosts by rank, else :func:`map_boost` by
    ``priorities`` (one per printed label, None: all 0) and thinness (the module's rule)."""
    from scipy import ndimage

    oriented_layers = [placement.orient(volume.layer(layer)) for layer in range(volume.layer_count)]
    objects = {}
    for layer, oriented in enumerate(oriented_layers):
        wanted = max((label.value for label, _ in printed if label.layer == layer), default=0)
        if wanted > 0:
            objects[layer] = ndimage.find_objects(oriented, max_label=wanted)
    fields, boxes = [], []
    for label, _ in printed:
        box = objects[label.layer][label.value - 1]
        fields.append(label_field(oriented_layers[label.layer], label.value, box, smooth))
        boxes.append([[piece.start for piece in box], [piece.stop for piece in box]])
    if ranks is None:
        boost = map_boost(fields, priorities)
        fields = yielding(fields, boost)
    else:
        boost = np.array([BOOST * (len(ranks) - rank) for rank in ranks], dtype=np.float32)
    shape = volume.shape
    return LabelPrint(tuple(label for label, _ in printed), tuple(fields),
                      np.array([code for _, code in printed], dtype=np.uint8), boost,
                      placement.oriented_origin(shape), placement.spacing, np.array(boxes, dtype=np.int64))


def _plane(field: LabelField, k: float) -> np.ndarray | None:
    """A field's values on the oriented plane at (fractional) index ``k`` along z, linear between its
    node planes, or None where the plane misses the field's box."""
    local = k - field.start[0]
    count = field.values.shape[0]
    if not 0.0 <= local <= count - 1:
        return None
    below = min(int(np.floor(local)), count - 2)
    weight = np.float32(local - below)
    return field.values[below] + weight * (field.values[below + 1] - field.values[below])


def _cells(centres: np.ndarray, origin: float, spacing: float, first: int, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel centre's node cell along one axis (-1 off the grid, nodes - 1 past it) and its fraction."""
    position = (centres - origin) / spacing - first
    cell = np.floor(position)
    fraction = (position - cell).astype(np.float32)
    cell = cell.astype(np.int64)
    cell[cell < 0] = -1
    cell[cell > nodes - 2] = nodes - 1
    return cell, fraction


def layer_masks(plan: LabelPrint, z_mm: float, grid: Grid, materials: int) -> tuple[np.ndarray, np.ndarray]:
    """One layer's packed masks ((materials + 1, H, ceil(W / 8)) uint8: the solid mask, then one per material
    code 1..materials; a label of code 0 is in the solid mask only) and their set pixels ((materials + 1,) int64)
    at printer height ``z_mm``."""
    planes = np.zeros((materials + 1, grid.height, -(-grid.width // 8)), dtype=np.uint8)
    counts = np.zeros(materials + 1, dtype=np.int64)
    k = (z_mm - plan.origin[0]) / plan.spacing[0]
    chosen = [(index, values, field.start) for index, field in enumerate(plan.fields)
              if (values := _plane(field, k)) is not None]
    if not chosen:
        return planes, counts
    low = np.min([start[1:] for _, _, start in chosen], axis=0)
    high = np.max([start[1:] + values.shape for _, values, start in chosen], axis=0)
    rows_n, columns_n = (int(n) for n in high - low)
    fields = np.full((len(chosen), rows_n, columns_n), FAR_OUTSIDE, dtype=np.float32)
    boxes = np.zeros((len(chosen), 4), dtype=np.int64)
    for slot, (_, values, start) in enumerate(chosen):
        y0, x0 = (int(n) for n in start[1:] - low)
        fields[slot, y0:y0 + values.shape[0], x0:x0 + values.shape[1]] = values
        boxes[slot] = (y0, y0 + values.shape[0], x0, x0 + values.shape[1])
    picked = np.array([index for index, _, _ in chosen])
    x, y = grid.centres()
    row_cell, row_frac = _cells(y, plan.origin[1], plan.spacing[1], int(low[0]), rows_n)
    row_cell[row_cell > rows_n - 2] = -1
    col_cell, col_frac = _cells(x, plan.origin[2], plan.spacing[2], int(low[1]), columns_n)
    cell_start = np.searchsorted(col_cell, np.arange(columns_n)).astype(np.int64)
    _label_codes(fields, np.ascontiguousarray(plan.boost[picked]), np.ascontiguousarray(plan.codes[picked]), boxes,
                 CRACK_VOXELS, row_cell, row_frac, cell_start, col_frac, planes, counts)
    return planes, counts
