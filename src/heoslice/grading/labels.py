"""The sub-region labels of one layer: every family's field painted outermost first, nested shells after.

Labels number every solid pixel's sub-region across the layer (family f's sub-region k
is base[f] + k). A :class:`heoslice.grading.cache.GradingCache` kept from layer to layer
lets a family whose rings' edges are the previous layer's, value for value (an extruded
part), take that layer's field, and a whole layer its labels.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from heoslice.grading.cache import GradingCache, PaintedLabels, RingMemo
from heoslice.grading.edges import ring_edges, ring_geometry
from heoslice.grading.families import Family, family_layout, layer_families
from heoslice.grading.field import LABEL_TYPES, FamilyField, family_field, label_dtype
from heoslice.grading.labels_kernels import disc_winding
from heoslice.grading.spec import RegionSpec
from heoslice.layers.rasterising import Grid, solid_mask

#: How far (mm) the disc around an island's pixel centres must stay from the layer's other loops for
#: :func:`_alone_in_boxes`: far beyond the rounding of the rasteriser's inside test.
_DISC_MARGIN_MM = 1e-6


#: Most (family, loop) bounding-box tests made at once by :func:`_alone_in_boxes` (two bools each: 8 MB).
_NEAR_TESTS = 1 << 22


@dataclass(frozen=True)
class LayerRegions:
    """The sub-regions of one layer.

    ``label`` ((rows, cols) uint8/16/32 over pixel ``box`` = (row0, row1, col0, col1))
    numbers every solid pixel's sub-region across the layer: family f's sub-region k
    is ``base[f] + k`` (k = 1..N_R; a nested shell keeps its own material: k = 0),
    0 is empty; a layer of one family of one sub-region labelled from the packed mask has one
    value seen at every pixel (read-only, no memory). ``families``/``fields`` are aligned,
    outermost first (the first field's ``index`` may share the label's memory: it is labelled in
    place, not copied).
    """

    box: tuple[int, int, int, int]
    label: np.ndarray
    families: tuple[Family, ...]
    fields: tuple[FamilyField, ...]
    base: np.ndarray

    @property
    def label_count(self) -> int:
        """Labels in use are 1 .. label_count - 1."""
        return int(self.base[-1]) if len(self.base) else 1


def layer_regions(points: np.ndarray, offsets: np.ndarray, area: np.ndarray, parent: np.ndarray,
                  mask: np.ndarray | None, grid: Grid, spec: RegionSpec, packed: np.ndarray | None = None,
                  cache: GradingCache | None = None) -> LayerRegions:
    """Sub-regions of one layer: loops (points (p, 2) mm, offsets (l+1,), signed areas and parents
    (l,) within the layer) and the layer's solid mask ((height, width) bool).

    Families are painted outermost first, each over its own solid pixels; a family
    inside another family's solid (a nested shell) is painted after it, so the inner
    shell wins where shells overlap. Without the bool ``mask``, from the ``packed`` one
    only (:func:`heoslice.layers.rasterising.packed_mask`; the droplet masks' path, which reads
    labels only where the layer is solid), the outermost family labels its whole box:
    pixels off the solid there hold labels too.

    ``cache`` (kept by the caller from layer to layer, same grid and spec) holds the previous
    layer's fields by their rings' edges (:func:`ring_geometry`): a family whose edges are the
    same, value for value (an extruded part), takes its field from there; a family measured
    afresh takes the edge trees and lattice passes of its ring sets that are the same (holes
    that stay while another changes). When every family's field is the previous layer's, and
    was the layer's before that, every island is alone in its box (:func:`_alone_in_boxes`) and
    the ``packed`` solid bits are the previous layer's, so are the labels: that array is
    returned again (callers only read labels).
    """
    families = tuple(layer_families(area, parent))
    if not families:
        return LayerRegions((0, 0, 0, 0), np.zeros((0, 0), LABEL_TYPES[0]), (), (), np.ones(1, np.int64))
    # the outermost family (label base 1) is labelled by its own expansion, saving a pass over ~15 MP
    masks = [None if number or family.nested else mask for number, family in enumerate(families)]
    keys = _family_keys(points, offsets, families, masks) if cache is not None else [None] * len(families)
    before = {} if cache is None else cache.fields_for(keys)
    painted = None if cache is None else cache.take_painted(keys)
    memo = RingMemo() if cache is None else cache.ring_memo()
    # the outermost family last: its index becomes the labels of them all, as wide as their labels need
    others = [_layer_field(points, offsets, family, grid, spec, family_mask, 0,
                           None if key is None else before.get(key), memo)
              for family, family_mask, key in zip(families[1:], masks[1:], keys[1:])]
    outermost = _layer_field(points, offsets, families[0], grid, spec, masks[0], 1,
                             None if keys[0] is None else before.get(keys[0]), memo,
                             headroom=int(_label_sizes(families[1:], others).sum()))
    fields = (outermost, *others)
    # the outermost family's index becomes the labels (no copy of ~15 MP) unless its field may serve the next
    # layer: when the last layer had it too (an extruded stretch; the stretch's first layer measures it again)
    copy_first = len(fields) > 1 and cache is not None and cache.repeats(keys[0])
    if cache is not None:
        cache.keep_layer(keys, fields, memo, keep_first=copy_first or len(fields) == 1)
    boxes = np.array([field.box for field in fields])
    box = (int(boxes[:, 0].min()), int(boxes[:, 1].max()), int(boxes[:, 2].min()), int(boxes[:, 3].max()))
    base = np.concatenate([[1], 1 + np.cumsum(_label_sizes(families, fields))]).astype(np.int64)
    # the outermost family labels its box by its own expansion: only the others may take the solid pixels of theirs
    alone = np.r_[False, _alone_in_boxes(points, offsets, families[1:], [field.box for field in fields[1:]], grid)]
    # painted from fields alone and the solid bits: the same fields, islands and bits paint the same labels
    # (kept for the next layer only when this one's fields are all the last one's: an extruded part)
    paintable = (cache is not None and packed is not None and None not in keys and all(key in before for key in keys)
                 and bool(alone[1:].all()))
    if paintable and painted is not None and np.array_equal(painted.packed, packed):
        cache.painted = painted
        return LayerRegions(box, painted.label, families, fields, base)
    painted = None  # freed before this layer's labels are painted
    label = _paint_labels(points, offsets, families, fields, base, box, alone, mask, packed, grid, copy_first)
    if paintable:
        cache.painted = PaintedLabels(keys, packed.copy(), label)
    return LayerRegions(box, label, families, fields, base)


def _label_sizes(families: tuple[Family, ...], fields) -> np.ndarray:
    """(f,) int: the labels each family takes, its N_R and its label base's own (a nested shell's: one)."""
    return np.array([1 if family.nested else field.layout.count + 1 for family, field in zip(families, fields)],
                    dtype=np.int64)


def _family_keys(points: np.ndarray, offsets: np.ndarray, families: tuple[Family, ...], masks: list) -> list:
    """Per family, the key of its field in a :class:`GradingCache` (nested?, outermost?, its rings' edges as
    bytes), or None for a family labelled from the layer's bool mask (its labels are the mask's)."""
    keyed = [number for number, family_mask in enumerate(masks) if family_mask is None]
    geometry = dict(zip(keyed, ring_geometry(points, offsets, [(families[n].outer, *families[n].holes)
                                                               for n in keyed])))
    return [(family.nested, int(number == 0), geometry[number]) if number in geometry else None
            for number, family in enumerate(families)]


def _paint_labels(points: np.ndarray, offsets: np.ndarray, families: tuple[Family, ...],
                  fields: tuple[FamilyField, ...], base: np.ndarray, box: tuple[int, int, int, int],
                  alone: np.ndarray, mask: np.ndarray | None, packed: np.ndarray | None, grid: Grid,
                  copy_first: bool) -> np.ndarray:
    """The layer's labels over ``box``: the outermost family's index, then every other family's labels (base
    + k, a nested shell base) painted over its own solid pixels (all the box's solid pixels where it is
    ``alone``). The outermost family's index is the label array itself when it spans the box, unless
    ``copy_first`` (other families paint over it and the field serves the next layer)."""
    first = fields[0]
    dtype = label_dtype(int(base[-1]) - 1)
    if first.box == box and _constant(first.index) is None:
        # as wide as the outermost family's index (made as wide as all the labels): it may be the labels (one value
        # seen at every pixel is filled in, in the narrowest width)
        dtype = np.result_type(dtype, first.index.dtype)
    if len(fields) == 1 and first.box == box and (value := _constant(first.index)) is not None:
        # one family of one sub-region: its one label seen at every pixel of the box, no array of ~15 MP
        return np.broadcast_to(np.array(value, dtype=dtype), first.index.shape)
    if first.box == box and first.index.dtype == dtype and first.index.flags.writeable and not copy_first:
        label = first.index  # the outermost family spans the layer's box: no copy of ~15 MP
    elif first.box == box:
        label = np.empty((box[1] - box[0], box[3] - box[2]), dtype=dtype)  # the copy of its labels fills it
    else:
        label = np.zeros((box[1] - box[0], box[3] - box[2]), dtype=dtype)
    for number, (family, field) in enumerate(zip(families, fields)):
        r0, r1, c0, c1 = field.box
        if r1 <= r0 or c1 <= c0:
            continue
        target = label[r0 - box[0]:r1 - box[0], c0 - box[2]:c1 - box[2]]
        if number == 0:
            # the outermost family's labels cover its box's solid pixels; everything after paints its own region
            if label is not first.index:
                if (constant := _constant(first.index)) is not None:
                    target.fill(constant)  # one label seen at every pixel: a fill, not a cast of a broadcast
                else:
                    np.copyto(target, first.index, casting="unsafe")
            continue
        solid = _solid_in(mask, packed, field.box)
        if not alone[number]:
            solid = solid & _family_mask(points, offsets, family, grid, field.box)
        # in the labels' own width: an index plus base's int64 would make a copy of the box up to 8x wider
        if family.nested:
            value = base[number]
        elif (constant := _constant(field.index)) is not None:  # one sub-region: one label, no array of the box
            value = base[number] + constant
        else:
            value = np.add(field.index, int(base[number]), dtype=label.dtype)  # a Python int takes that width
        np.copyto(target, value, where=solid, casting="unsafe")
    return label


def _constant(index: np.ndarray) -> int | None:
    """The one value of an index that holds one value seen at every pixel (a one-sub-region family's,
    :func:`heoslice.grading.field.family_field`), else None (also for an empty index: a nested shell's)."""
    return int(index.flat[0]) if index.size and not any(index.strides) else None


def _layer_field(points: np.ndarray, offsets: np.ndarray, family: Family, grid: Grid, spec: RegionSpec,
                 mask: np.ndarray | None, label_base: int, same: FamilyField | None,
                 memo: RingMemo, headroom: int = 0) -> FamilyField:
    """One family's field for :func:`layer_regions`: measured (``memo`` and ``headroom`` as :func:`family_field`),
    or ``same``, the previous layer's field of a family with the same rings' edges, with this layer's start
    edges and loop numbers."""
    if same is None:
        return family_field(points, offsets, family, grid, spec, pixels=not family.nested, mask=mask,
                            label_base=label_base, memo=memo, headroom=headroom)
    loops = family_layout(family, spec)
    # only contours with colours or material fractions read them (contour_values)
    start_edges = functools.cache(lambda: ring_edges(points, offsets, loops.start))
    return replace(same, start_edges=start_edges,
                   layout=replace(same.layout, start=loops.start, end=loops.end if same.layout.end else ()))


def _solid_in(mask: np.ndarray | None, packed: np.ndarray | None, box: tuple[int, int, int, int]) -> np.ndarray:
    """(rows, cols) bool: the layer's solid pixels in a pixel box, from the bool mask or else the packed one."""
    r0, r1, c0, c1 = box
    if mask is not None:
        return mask[r0:r1, c0:c1]
    bits = np.unpackbits(packed[r0:r1, c0 // 8:-(-c1 // 8)], axis=1).view(bool)
    return bits[:, c0 % 8:c0 % 8 + c1 - c0]


def _alone_in_boxes(points: np.ndarray, offsets: np.ndarray, families: tuple[Family, ...],
                    boxes: list[tuple[int, int, int, int]], grid: Grid) -> np.ndarray:
    """(f,) bool per family: whether the layer's solid pixels in its pixel box are all pixels of the family
    (:func:`_family_mask`), so its rings need no rasterising again: an island standing in a hole, a pin
    in a plate. The layer is solid where all its loops wind more than 0 times around a pixel centre, the
    family's pixels where its own loops do; so it holds when the other loops wind at most 0 times around a
    disc holding the box's pixel centres and none of them meets it (compiled
    :func:`heoslice.grading.labels_kernels.disc_winding`). Only loops whose bounding box, grown by the disc's
    radius, holds its centre can meet the disc or wind around it."""
    if not families:
        return np.zeros(0, dtype=bool)
    box = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    low = np.column_stack([grid.x_left + (box[:, 2] + 0.5) * grid.px, grid.y_top - (box[:, 1] - 0.5) * grid.py])
    high = np.column_stack([grid.x_left + (box[:, 3] - 0.5) * grid.px, grid.y_top - (box[:, 0] + 0.5) * grid.py])
    centre, reach = 0.5 * (low + high), 0.5 * np.hypot(*(high - low).T) + _DISC_MARGIN_MM
    loop_low, loop_high = np.minimum.reduceat(points, offsets[:-1]), np.maximum.reduceat(points, offsets[:-1])
    near = []
    step = max(1, _NEAR_TESTS // len(loop_low))  # families at once: (step, loops) tests
    for first in range(0, len(families), step):
        c, r = centre[first:first + step, None, :], reach[first:first + step, None, None]
        near += list(map(np.flatnonzero, np.all((c >= loop_low - r) & (c <= loop_high + r), axis=2)))
    alone = np.zeros(len(families), dtype=bool)
    for number, (family, loops) in enumerate(zip(families, near)):
        own = {family.outer, *family.holes}
        others = [loop for loop in loops.tolist() if loop not in own]
        winding = disc_winding(points, offsets, np.array(others), centre[number], reach[number]) if others else 0
        alone[number] = winding is not None and winding <= 0
    return alone


def _family_mask(points: np.ndarray, offsets: np.ndarray, family: Family, grid: Grid,
                 box: tuple[int, int, int, int]) -> np.ndarray:
    """(rows, cols) bool over a pixel box: pixel centres inside the family's outer ring and outside its holes."""
    loops = (family.outer,) + family.holes
    sizes = np.array([offsets[loop + 1] - offsets[loop] for loop in loops])
    ring_points = np.concatenate([points[offsets[loop]:offsets[loop + 1]] for loop in loops])
    r0, r1, c0, c1 = box
    sub = Grid(width=c1 - c0, height=r1 - r0, x_left=grid.x_left + c0 * grid.px, y_top=grid.y_top - r0 * grid.py,
               px=grid.px, py=grid.py)
    return solid_mask(ring_points, np.concatenate([[0], np.cumsum(sizes)]), sub)


def family_of(regions: LayerRegions) -> list[np.ndarray]:
    """For each family, the (rows, cols) bool mask of its labelled pixels within its own box."""
    out = []
    for number, field in enumerate(regions.fields):
        r0, r1, c0, c1 = field.box
        b = regions.box
        sub = regions.label[r0 - b[0]:r1 - b[0], c0 - b[2]:c1 - b[2]]
        out.append((sub >= regions.base[number]) & (sub < regions.base[number + 1]))
    return out


def label_fractions(regions: LayerRegions, fraction_at) -> np.ndarray:
    """Fraction of the target material per label ((label_count,) float in [0, 1]).

    ``fraction_at(r)`` is the distribution function ((n,) -> (n,)); sub-region k of a
    family with N_R sub-regions gets f(k / N_R) clipped to [0, 1] (eq. 1: M1 at f <= 0,
    M2 at f >= 1); a nested shell's label gets 0 (its own material); label 0 (empty) 0.
    """
    out = np.zeros(regions.label_count)
    for number, (family, field) in enumerate(zip(regions.families, regions.fields)):
        if family.nested:
            continue
        count = field.layout.count
        k = np.arange(1, count + 1)
        out[regions.base[number] + k] = np.clip(np.asarray(fraction_at(k / count), dtype=np.float64), 0.0, 1.0)
    return out
