"""The delivered-material report of a stack: what each material's droplet masks put where, against the design.

Per material: its voxels (set pixels of its droplet mask over all layers), volume (voxels x pixel area x layer
height, mm^3) and share of the solid. With a design: the designed against the delivered share of each part
(:func:`part_shares`), of every 2 mm x 2 mm window of every layer (a window starting every quarter of its side,
about 0.5 mm, in both directions: :class:`WindowGrid`; the worst is reported) and of every band of a
:data:`BandSource` (bands of r, or of the designed share: :func:`share_bands`). A solid pixel in no droplet mask,
or in two, is a fault named by layer and position (:func:`mask_faults`, which ``verify`` uses).

"Designed" per stack kind (docs in README, ``verify``):

- a multi-part job: each part is designed all of its material; its designed volume is its own volume less what
  parts of a lower rank take where they overlap (computed from the meshes by the caller);
- a graded or coloured stack: the per-pixel mix the halftone was given, supplied by a :data:`DesignSource`
  (e.g. :func:`preview_design`: the same slice's ``--rgba`` stack, whose colour is eq. 1's blend).

The work is a function of one layer's arrays (:func:`layer_tally`) plus a reduction (:func:`reduce_tallies`),
so layers can be tallied in any order or in parallel; the bit logic runs on ``np.packbits`` rows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from heoslice.stack.manifest import widest_masks
from heoslice.stack.packed import Bits, partition_counts
from heoslice.stack.read import read_layer_channels, read_layer_mask, read_layer_pixels

#: Side of the windows the design is checked over, mm.
WINDOW_MM = 2.0
#: Least side of a window, pixels: WINDOW_MM at 600 dpi, the paper's resolution. A coarser stack's windows hold as
#: many pixels (as many droplets), so are larger in mm: no halftone delivers a share within 2 points over a few
#: dozen droplets (2 mm at 150 dpi is 12 x 12 px, less than one 16 x 16 tile of the ordered dither).
WINDOW_LEAST_PIXELS = 47
#: Windows start every 1 / WINDOW_STEPS of a window's side (rounded down to whole pixels) in both directions, so a
#: deviation straddling the edges of a tiling is seen whole by some window (a window at every pixel would add each
#: pixel into a window's width of sums, 47 at 600 dpi, instead of WINDOW_STEPS).
WINDOW_STEPS = 4
#: A window is compared when at least this share of its pixels is solid: in a window the part barely enters,
#: one droplet is a large share, which no halftone can match.
WINDOW_MIN_SOLID = 0.5
#: Name of the one material of a stack without droplet masks.
SOLID = "solid"

#: The designed mix of one layer: (K, h, w) float, per solid pixel each material's share (summing to 1), in
#: the order of the layer's droplet masks; None when the layer has no design to compare.
DesignSource = Callable[[int], "np.ndarray | None"]
#: The band of every pixel of one layer, given the layer index and its designed mix: (h, w) int, 0..B-1, or -1
#: for a pixel in no band (e.g. bands of r, the distance to the reference, from a recorded design).
BandSource = Callable[[int, "np.ndarray | None"], np.ndarray]


@dataclass(frozen=True, slots=True)
class PixelFault:
    """Pixels of one layer that break "every solid pixel in exactly one droplet mask": how many, and the first
    (row, column) in reading order."""

    count: int
    first: tuple[int, int]


@dataclass(frozen=True, slots=True)
class MaskFaults:
    """One layer's faults: solid pixels in no mask, pixels in two or more masks, mask pixels outside the solid
    (None: no such pixel)."""

    uncovered: PixelFault | None
    doubled: PixelFault | None
    outside: PixelFault | None


@dataclass(frozen=True, slots=True)
class WindowGrid:
    """The windows a layer is checked over: ``size`` (rows, columns) pixels, their top-left pixels every ``step``
    (rows, columns) pixels from the image's top-left, plus the windows flush with its bottom and right edges."""

    size: tuple[int, int]
    step: tuple[int, int]

    def starts(self, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The windows' first rows and first columns on an (h, w) image."""
        return (window_starts(shape[-2], self.size[0], self.step[0]),
                window_starts(shape[-1], self.size[1], self.step[1]))


@dataclass(frozen=True, slots=True)
class Window:
    """A 2 mm x 2 mm window of one layer against the design: its layer, top-left pixel (row, column), solid
    pixels, the material compared and its designed and delivered share of the window's solid."""

    layer: int
    pixel: tuple[int, int]
    solid: int
    material: int
    designed: float
    delivered: float

    @property
    def difference(self) -> float:
        return self.delivered - self.designed


@dataclass(frozen=True, slots=True)
class BandTable:
    """Per band: solid pixels (B,), and per material (K, B) the delivered voxels and the designed shares summed
    over the band's solid pixels. Tables of several layers add up."""

    solid: np.ndarray
    delivered: np.ndarray
    designed: np.ndarray

    def __add__(self, other: BandTable) -> BandTable:
        return BandTable(self.solid + other.solid, self.delivered + other.delivered, self.designed + other.designed)


@dataclass(frozen=True, slots=True)
class LayerTally:
    """One layer's contribution: (K,) voxels per material, solid pixels, its faults, its worst window (None
    without a design, or without a window solid enough) and its band table (None without bands)."""

    index: int
    voxels: np.ndarray
    solid: int
    faults: MaskFaults
    worst: Window | None
    bands: BandTable | None = None


@dataclass(frozen=True, slots=True)
class CodedDesign:
    """A layer's design as a code per solid pixel (r's step, for a field interior) and tables per code, as
    :func:`coded_tally` reads it: ``box`` (first row, end row, first column, end column) the pixels ``codes``
    ((rows, columns) uint16) covers; ``shares`` (n,) float32 the target's designed share per code (the start's is 1
    minus it, every other mask's 0); ``bands`` (n,) int64 the band per code, of ``band_count``; ``start`` and
    ``target`` the two materials' mask indices."""

    box: tuple[int, int, int, int]
    codes: np.ndarray
    shares: np.ndarray
    bands: np.ndarray
    band_count: int
    start: int
    target: int


@dataclass(frozen=True, slots=True)
class MaterialShare:
    """One material of the report: name, voxels, volume (mm^3), share of the solid (0..1)."""

    name: str
    voxels: int
    volume_mm3: float
    share: float


@dataclass(frozen=True, slots=True)
class PartShare:
    """One part (or the parts of one material together) against the design: names, material, designed and
    delivered volume (mm^3) and share of the solid (designed: of the designed solid)."""

    parts: tuple[str, ...]
    material: str
    designed_mm3: float
    delivered_mm3: float
    designed: float
    delivered: float

    @property
    def difference(self) -> float:
        return self.delivered - self.designed


@dataclass(frozen=True, slots=True)
class BandShare:
    """One band over the whole stack: its index, solid voxels, and per material (K,) the designed and delivered
    share of the band's solid."""

    band: int
    voxels: int
    designed: tuple[float, ...]
    delivered: tuple[float, ...]

    @property
    def difference(self) -> float:
        """The largest |delivered - designed| over the materials."""
        return max(abs(d - p) for d, p in zip(self.delivered, self.designed))


@dataclass(frozen=True, slots=True)
class MaterialReport:
    """The whole stack's report: per material, the solid's voxels and volume, the worst window (None without a
    design), the layers with faults, in layer order, and the bands (() without bands)."""

    materials: tuple[MaterialShare, ...]
    solid_voxels: int
    solid_mm3: float
    worst: Window | None
    faults: tuple[tuple[int, MaskFaults], ...]
    bands: tuple[BandShare, ...] = ()


def _first_set(packed: np.ndarray, row_offset: int = 0) -> PixelFault | None:
    """How many bits of (h, ceil(w / 8)) packed rows are set, and the first (row + ``row_offset``, column), or
    None."""
    if not np.count_nonzero(packed):  # the common case, a byte test far cheaper than counting bits
        return None
    count = int(np.bitwise_count(packed).sum())
    flat = int(np.flatnonzero(packed)[0])
    row, byte = divmod(flat, packed.shape[1])
    bit = int(np.flatnonzero(np.unpackbits(packed[row, byte:byte + 1]))[0])
    return PixelFault(count, (row + row_offset, 8 * byte + bit))


def masks_partition(solid: np.ndarray, masks) -> bool:
    """Whether the droplet masks partition the solid: no bit in two masks, their union exactly ``solid``
    (packed rows as :func:`mask_faults` takes them), by :func:`heoslice.stack.packed.partition_counts`' one
    compiled pass per file; :func:`mask_faults` says where a layer that fails it is wrong."""
    masks = list(masks)
    if not masks:
        return not solid.any()
    every_row = (0, solid.shape[0])
    return partition_counts(Bits(solid, every_row), [Bits(mask, every_row) for mask in masks])[1]


def mask_faults(solid: np.ndarray, masks, row_offset: int = 0, clean_checked: bool = False) -> MaskFaults:
    """Faults of one layer's droplet masks against its solid mask, on packed bits: ``solid`` (h, ceil(w / 8))
    uint8 and ``masks`` (K, h, ceil(w / 8)) uint8 (``np.packbits(..., axis=-1)``); ``row_offset``: the layer
    row of their first row (a band of rows holding every set bit). A layer :func:`masks_partition` passes has
    none (asked first unless ``clean_checked``: the caller asked)."""
    if not clean_checked and masks_partition(solid, masks):
        return MaskFaults(None, None, None)
    seen = np.zeros_like(solid)
    doubled = np.zeros_like(solid)
    for mask in masks:
        doubled |= seen & mask
        seen |= mask
    return MaskFaults(_first_set(solid & ~seen, row_offset), _first_set(doubled, row_offset),
                      _first_set(seen & ~solid, row_offset))


def pixel_position(manifest: dict, pixel: tuple[int, int]) -> tuple[float, float]:
    """Model coordinates (x, y) mm of the centre of pixel (row, column) (docs/stack-format.md)."""
    (px, py), (x_left, y_top) = manifest["pixel_size_mm"], manifest["image"]["origin_mm"]
    row, column = pixel
    return x_left + (column + 0.5) * px, y_top - (row + 0.5) * py


def where(manifest: dict, pixel: tuple[int, int]) -> str:
    """'pixel x C, y R (x X, y Y mm)' for a message."""
    x, y = pixel_position(manifest, pixel)
    return f"pixel x {pixel[1]}, y {pixel[0]} (x {x:.4f}, y {y:.4f} mm)"


def fault_lines(index: int, faults: MaskFaults, manifest: dict) -> list[str]:
    """One problem line per kind of fault of layer ``index``, naming the count and the first pixel."""
    kinds = (("uncovered", "solid pixel(s) in no droplet mask"), ("doubled", "pixel(s) in two or more droplet masks"),
             ("outside", "droplet-mask pixel(s) outside the layer's solid pixels"))
    lines = []
    for field, text in kinds:
        fault = getattr(faults, field)
        if fault is not None:
            lines.append(f"layer {index}: {fault.count} {text}, first at {where(manifest, fault.first)}")
    return lines


def window_grid(manifest: dict) -> WindowGrid:
    """The windows of a stack: WINDOW_MM x WINDOW_MM at its pixel size, at least WINDOW_LEAST_PIXELS a side, a
    step of a WINDOW_STEPS-th of that (at least 1 pixel)."""
    px, py = manifest["pixel_size_mm"]
    size = max(WINDOW_LEAST_PIXELS, round(WINDOW_MM / py)), max(WINDOW_LEAST_PIXELS, round(WINDOW_MM / px))
    return WindowGrid(size, (max(1, size[0] // WINDOW_STEPS), max(1, size[1] // WINDOW_STEPS)))


def least_solid(grid: WindowGrid) -> int:
    """The solid pixels a window needs to be compared (WINDOW_MIN_SOLID of it); a band of fewer solid voxels over
    the whole stack is reported but not judged either: over so few droplets no halftone holds a share."""
    return int(np.ceil(WINDOW_MIN_SOLID * grid.size[0] * grid.size[1]))


def window_starts(length: int, size: int, step: int) -> np.ndarray:
    """First pixels of the windows along one axis of ``length`` pixels: every multiple of ``step`` up to
    ``length - size``, and ``length - size`` itself (the window flush with the far edge); (0,) for an image
    narrower than a window."""
    last = max(length - size, 0)
    return np.unique(np.append(np.arange(0, last + 1, step), last))


def _window_sums(values: np.ndarray, size: tuple[int, int], starts: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Sums of (..., h, w) values over the windows of ``size`` (rows, columns) whose top-left pixels are ``starts``
    (rows, columns; increasing, each window inside the image but the last, which is cut at its edge): each
    window's columns summed along its rows, then those sums along its columns, by ``np.add.reduceat`` over the
    windows' (start, end) bounds (exact sums; each pixel is added into the sums of the windows along its row that
    hold it, about WINDOW_STEPS):
    (..., len(rows), len(columns)). Integers and booleans are summed as int64, floats as float64."""
    total = np.int64 if values.dtype.kind in "biu" else np.float64
    sums = values
    for axis, length, first in ((-1, size[1], starts[1]), (-2, size[0], starts[0])):
        bounds = np.stack([first, first + length], axis=1).ravel()
        bounds = bounds[:-1] if bounds[-1] >= sums.shape[axis] else bounds  # the last window ends at the edge
        reduced = np.add.reduceat(sums, bounds, axis=axis, dtype=total)  # even entries: the windows' sums
        sums = reduced[..., ::2] if axis == -1 else reduced[..., ::2, :]
    return sums


def worst_window(index: int, solid: np.ndarray, masks: np.ndarray, designed: np.ndarray,
                 grid: WindowGrid) -> Window | None:
    """The window of one layer whose delivered share of some material is furthest from its designed share, over
    the windows of ``grid`` (every ``grid.step`` pixels, not only a tiling) at least WINDOW_MIN_SOLID solid.
    solid (h, w) bool; masks (K, h, w) bool; designed (K, h, w) float shares per pixel. Only the windows that
    reach the solid's bounding box are summed, over the pixels they cover (the others hold no solid pixel)."""
    filled = [np.flatnonzero(solid.any(axis=axis)) for axis in (1, 0)]
    if not len(filled[0]):
        return None
    starts = []
    for first, size, solid_at in zip(grid.starts(solid.shape), grid.size, filled):
        starts.append(first[(first + size > solid_at[0]) & (first <= solid_at[-1])])
    (rows, columns), (height, width) = starts, grid.size
    if not len(rows) or not len(columns):  # a step longer than the window can pass the solid by
        return None
    crop = np.s_[rows[0]:rows[-1] + height, columns[0]:columns[-1] + width]
    solid = solid[crop]
    relative = (rows - rows[0], columns - columns[0])
    solid_count = _window_sums(solid, grid.size, relative)
    compared = solid_count >= least_solid(grid)
    if not compared.any():
        return None
    count = solid_count[compared]
    delivered = np.stack([_window_sums(mask[crop] & solid, grid.size, relative)[compared] for mask in masks]) / count
    planned = np.stack([_window_sums(np.where(solid, share[crop], np.float32(0.0)), grid.size, relative)[compared]
                        for share in designed]) / count
    material, position = np.unravel_index(int(np.argmax(np.abs(delivered - planned))), delivered.shape)
    row, column = np.argwhere(compared)[position]
    return Window(index, (int(rows[row]), int(columns[column])), int(count[position]), int(material),
                  float(planned[material, position]), float(delivered[material, position]))


def band_table(solid: np.ndarray, masks: np.ndarray, designed: np.ndarray, labels: np.ndarray,
               count: int) -> BandTable:
    """One layer's band table: solid (h, w) bool, masks (K, h, w) bool, designed (K, h, w) float shares,
    labels (h, w) int band of each pixel (-1: none), ``count`` bands."""
    band = labels[solid]
    keep = (band >= 0) & (band < count)
    band = band[keep]
    delivered = np.stack([np.bincount(band, weights=mask[solid][keep], minlength=count) for mask in masks])
    planned = np.stack([np.bincount(band, weights=share[solid][keep], minlength=count) for share in designed])
    return BandTable(np.bincount(band, minlength=count), delivered, planned)


def coded_tally(index: int, bits: Sequence[Bits], design: CodedDesign, grid: WindowGrid, width: int,
                counted: LayerTally | None = None) -> LayerTally:
    """One layer's tally (:func:`layer_tally`'s) against a design per pixel, from its files' bits (``bits``: its
    solid pixels, then its droplet masks' in manifest order; ``width`` pixels a row): the worst window and the
    band table as :func:`worst_window` and :func:`band_table` give them from per-pixel arrays, in one compiled
    pass over the packed rows (:func:`heoslice.stack.report_kernels.design_tally`: the sums in another order, so
    equal to rounding). ``counted``: the layer's counts from its verified manifest entry (:func:`counted_tally`),
    taken instead of counting and checking its bits again."""
    from heoslice.stack.report_kernels import design_tally

    solid = bits[0].rows
    if len(bits) == 1:  # a layer without droplet masks: its solid is the one material, nothing to compare
        pixels = int(np.bitwise_count(solid).sum())
        return counted or LayerTally(index, np.array([pixels]), pixels, MaskFaults(None, None, None), None)
    masks = np.stack([b.rows for b in bits[1:]])
    count = design.band_count
    counts, delivered = np.zeros(count, np.int64), np.zeros((len(masks), count), np.int64)
    planned, worst = np.zeros((len(masks), count)), np.zeros(6)
    rows, columns = grid.starts((solid.shape[0], width))
    least = least_solid(grid)
    design_tally(solid, masks, np.array(design.box, np.int64), np.ascontiguousarray(design.codes, np.uint16),
                 np.ascontiguousarray(design.shares, np.float32), np.ascontiguousarray(design.bands, np.int64),
                 design.start, design.target, width, np.array(grid.size, np.int64), rows.astype(np.int64),
                 columns.astype(np.int64), least, counts, delivered, planned, worst)
    material, row, column, pixels, designed, got = worst
    window = None if material < 0 else Window(index, (int(row), int(column)), int(pixels), int(material),
                                              float(designed), float(got))
    table = BandTable(counts, delivered, planned)
    if counted is not None:
        return replace(counted, worst=window, bands=table)
    voxels = np.bitwise_count(masks).sum(axis=(1, 2)).astype(np.int64)
    return LayerTally(index, voxels, int(np.bitwise_count(solid).sum()), mask_faults(solid, masks), window, table)


def layer_tally(index: int, solid: np.ndarray, masks: np.ndarray, designed: np.ndarray | None = None,
                window: WindowGrid = WindowGrid((1, 1), (1, 1)), bands: np.ndarray | None = None,
                band_count: int = 0) -> LayerTally:
    """One layer's tally: solid (h, w) bool; masks (K, h, w) bool, the droplet masks (K = 0: the solid is the
    one material); designed (K, h, w) float per-pixel shares, or None; window: the windows; bands (h, w)
    int band labels of ``band_count`` bands (with a design), or None."""
    packed_solid = np.packbits(solid, axis=-1)
    if not len(masks):
        empty = MaskFaults(None, None, None)
        return LayerTally(index, np.array([int(np.bitwise_count(packed_solid).sum())]), int(solid.sum()), empty,
                          None)
    packed = np.packbits(masks, axis=-1)
    voxels = np.bitwise_count(packed).sum(axis=(1, 2)).astype(np.int64)
    worst = None if designed is None else worst_window(index, solid, masks, designed, window)
    table = None if designed is None or bands is None else band_table(solid, masks, designed, bands, band_count)
    return LayerTally(index, voxels, int(np.bitwise_count(packed_solid).sum()), mask_faults(packed_solid, packed),
                      worst, table)


def material_names(manifest: dict) -> list[str]:
    """The report's materials: the droplet masks' materials in mask order, or SOLID for a stack without."""
    widest = widest_masks(manifest)
    return [str(mask.get("material", f"mask {n + 1}")) for n, mask in enumerate(widest)] or [SOLID]


def reduce_tallies(manifest: dict, tallies: Sequence[LayerTally]) -> MaterialReport:
    """The stack's report from its layers' tallies (any order)."""
    names = material_names(manifest)
    (px, py), h = manifest["pixel_size_mm"], manifest["layer_height_mm"]
    voxel_mm3 = px * py * h
    voxels = np.zeros(len(names), dtype=np.int64)
    for tally in tallies:
        voxels[:len(tally.voxels)] += tally.voxels
    solid = sum(tally.solid for tally in tallies)
    windows = [tally.worst for tally in tallies if tally.worst is not None]
    worst = max(windows, key=lambda w: (abs(w.difference), -w.layer), default=None)
    faults = tuple((t.index, t.faults) for t in sorted(tallies, key=lambda t: t.index)
                   if any(getattr(t.faults, f) for f in ("uncovered", "doubled", "outside")))
    materials = tuple(MaterialShare(name, int(count), float(count * voxel_mm3), float(count / solid) if solid else 0.0)
                      for name, count in zip(names, voxels))
    tables = [tally.bands for tally in tallies if tally.bands is not None]
    return MaterialReport(materials, int(solid), float(solid * voxel_mm3), worst, faults,
                          band_shares(sum(tables[1:], tables[0])) if tables else ())


def band_shares(table: BandTable) -> tuple[BandShare, ...]:
    """The bands of a stack's summed table that hold solid voxels, each with its designed and delivered shares."""
    return tuple(BandShare(band, int(table.solid[band]), tuple(float(v) for v in table.designed[:, band] /
                                                               table.solid[band]),
                           tuple(float(v) for v in table.delivered[:, band] / table.solid[band]))
                 for band in np.flatnonzero(table.solid))


def tally_layer(directory: Path, manifest: dict, index: int, design: DesignSource | None = None,
                bands: BandSource | None = None, band_count: int = 0) -> LayerTally:
    """Read layer ``index`` of a verified stack (its files checked against their SHA-256 again) and tally it."""
    solid = read_layer_mask(directory, manifest, index)
    masks = read_layer_channels(directory, manifest, index)
    designed = None if design is None or not len(masks) else design(index)
    labels = None if bands is None or designed is None else bands(index, designed)
    return layer_tally(index, solid, masks, designed, window_grid(manifest), labels, band_count)


def counted_tally(manifest: dict, index: int) -> LayerTally | None:
    """Layer ``index``'s tally from the set-pixel counts its manifest entry records (verified against the files
    by :func:`heoslice.stack.verify_stack`, faults included), or None when a mask records no count."""
    entry = manifest["layers"][index]
    counts = [channel.get("solid_pixels") for channel in entry.get("channels", [])] or [entry["solid_pixels"]]
    if any(count is None for count in counts):
        return None
    return LayerTally(index, np.array(counts, dtype=np.int64), int(entry["solid_pixels"]),
                      MaskFaults(None, None, None), None)


def material_report(directory: Path, manifest: dict, design: DesignSource | None = None,
                    bands: BandSource | None = None, band_count: int = 0) -> MaterialReport:
    """The report of a stack :func:`heoslice.stack.verify_stack` passed, layer by layer; ``design`` gives each
    layer's designed mix, ``bands`` each pixel's band (of ``band_count``) to compare designed and delivered
    shares per band. Without a design a layer's counts come from its verified manifest entry when it records
    them (no file is read again)."""
    tallies = []
    for index in range(len(manifest["layers"])):
        counted = None if design is not None else counted_tally(manifest, index)
        tallies.append(counted or tally_layer(directory, manifest, index, design, bands, band_count))
    return reduce_tallies(manifest, tallies)


def share_bands(count: int = 10, material: int = 1) -> BandSource:
    """Bands of the designed share of mask ``material``: band b holds the pixels designed b / count .. (b + 1) /
    count of it (the last band includes 1). For a function of r that rises with r (linear) these are bands
    of r; a recorded design can give bands of r itself."""

    def bands(index: int, designed: np.ndarray | None) -> np.ndarray:
        return np.minimum((designed[material] * count).astype(np.int64), count - 1)

    return bands


def part_shares(manifest: dict, report: MaterialReport, designed_mm3: Sequence[float]) -> tuple[PartShare, ...]:
    """A multi-part job's parts against their design: each material's parts together (a material's voxels
    cannot be told apart by part), designed volume the sum of their ``designed_mm3`` (in the manifest's part
    order: each part's volume less what lower-ranked parts take where they overlap), delivered that material's
    volume; shares of the designed and of the delivered solid."""
    delivered = {share.name: share.volume_mm3 for share in report.materials}
    if list(delivered) == [SOLID]:
        delivered = {part["material"]: report.solid_mm3 for part in manifest["parts"]}
    groups: dict[str, list[int]] = {}
    for number, part in enumerate(manifest["parts"]):
        groups.setdefault(str(part["material"]), []).append(number)
    designed_total = sum(designed_mm3) or 1.0
    solid = report.solid_mm3 or 1.0
    shares = []
    for material, numbers in groups.items():
        designed = sum(designed_mm3[number] for number in numbers)
        got = delivered.get(material, 0.0)
        shares.append(PartShare(tuple(str(manifest["parts"][n]["name"]) for n in numbers), material, designed, got,
                                designed / designed_total, got / solid))
    return tuple(shares)


def preview_design(preview: Path, manifest: dict, colors: Sequence[Sequence[int]],
                   preview_manifest: dict) -> DesignSource:
    """The design of a two-material graded or coloured stack read from the same slice's RGBA preview stack
    (``slice --rgba``, same grid): each pixel's colour is eq. 1's blend start + f (target - start), so its
    target share f is the projection of (colour - start) on (target - start), clipped to [0, 1]. ``colors``:
    the two masks' display colours [start, target] in mask order (the manifest's ``grading.materials``)."""
    start, target = (np.asarray(color, dtype=np.int32) for color in colors)
    axis = target - start
    scale = float(axis @ axis)
    if not scale:
        raise ValueError("the two materials have one colour: a preview cannot tell their shares apart")
    if [manifest["image"][k] for k in ("width", "height")] != [preview_manifest["image"][k] for k in
                                                                ("width", "height")]:
        raise ValueError("the preview stack's layers are not the size of the stack's")

    def design(index: int) -> np.ndarray:
        pixels = read_layer_pixels(preview, preview_manifest, index)
        dot = sum((pixels[..., c].astype(np.int32) - start[c]) * axis[c] for c in range(3))
        f = np.clip(dot.astype(np.float32) / np.float32(scale), 0.0, 1.0)
        return np.stack([1.0 - f, f])

    return design
