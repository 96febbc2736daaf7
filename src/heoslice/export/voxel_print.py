"""``voxel-print``: a GrabCAD Voxel Print slice folder for Stratasys PolyJet printers (J-series).

Conventions (``docs/export-formats.md``): one RGB PNG per printer layer, all the same size, named
``slice_NNNNN.png`` bottom first; each material one exact colour (its ``grading.materials`` colour,
or white for a one-material stack), empty pixels the background colour (default black); 600 x 300 dpi
at a 0.027 mm pitch (the J750's high-mix mode) unless asked otherwise. The stack is resampled by
nearest sample, never blended, so every printed voxel keeps exactly one material: in the plane each
slice pixel takes the stack pixel under its centre, in z each slice the stack layer holding its
centre height. A slice's image data is written straight from the runs of one label along its sampled
rows (:mod:`heoslice.export.voxel_print_kernels`: literals and matches, never the RGB rows); a layer of
short runs (a dithered grading) has its rows coloured and deflated by zlib-ng instead. Refused: stacks
that cannot print (:mod:`heoslice.stack.printable`: RGBA previews sliced with ``--rgba``, every layer
empty), materials without a colour, two materials of one colour or one of the background's, a layer whose
droplet masks are not the first layer's (:func:`check_same_masks`).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from heoslice.deflate import run_code
from heoslice.errors import InputError
from heoslice.export.base import ExportFormat, ExportOptions, Sink
from heoslice.export.voxel_print_kernels import run_stream
from heoslice.pipeline.parallel import ordered_map
from heoslice.pngfile import deflated_png, scanlines_png
from heoslice.stack import MANIFEST, MAX_IMAGE_PIXELS, MAX_LAYERS, check_printable
from heoslice.stack.packed import Bits, layer_bits
from heoslice.stack.verify import StackPlan, verified_layer

#: The J750's Voxel Print resolution (dpi x, y) and layer pitch (mm).
DEFAULT_DPI = (600.0, 300.0)
DEFAULT_PITCH_MM = 0.027
DEFAULT_BACKGROUND = (0, 0, 0)
#: Colour of the one material of a stack without droplet masks.
SINGLE_MATERIAL = ("model", (255, 255, 255))
SUMMARY_FILE = "voxelprint.json"


def palette(manifest: dict, background: tuple[int, int, int],
            source: str | Path = MANIFEST) -> list[tuple[str, tuple[int, int, int]]]:
    """(name, colour) of every material in label order (label m + 1 is material m); InputError when the
    stack's materials cannot be told apart by one exact colour each (naming the manifest file ``source`` when a
    material has no colour there). Whether the stack can print at all is :func:`heoslice.stack.check_printable`'s
    rule, applied by :func:`write`."""
    channels = manifest["layers"][0].get("channels") if manifest["layers"] else None
    if not channels:
        materials = [SINGLE_MATERIAL]
    else:
        grading = manifest.get("grading") or {}
        colours = {m.get("name"): m.get("color") for m in grading.get("materials") or [] if isinstance(m, dict)}
        materials = []
        for channel in channels:
            colour = colours.get(channel.get("material"))
            if not (isinstance(colour, list) and len(colour) == 3 and all(isinstance(v, int) for v in colour)):
                raise InputError(f"{source}: material {channel.get('material')!r} has no [r, g, b] colour in "
                                 "grading.materials (voxel-print tells materials apart by colour)")
            materials.append((channel["material"], tuple(colour)))
    seen = {tuple(background): "the background"}
    for name, colour in materials:
        if colour in seen:
            advice = ("give it another colour in the materials file (--materials), or choose another --background "
                      "where the format takes one" if seen[colour] == "the background"
                      else "give one of them another colour in the materials file (--materials)")
            raise InputError(f"{source}: material {name!r} has colour {list(colour)}, the same as {seen[colour]}; "
                             f"the export tells materials apart by colour: {advice}")
        seen[colour] = f"material {name!r}"
    return materials


def check_same_masks(manifest: dict, source: str | Path = MANIFEST) -> None:
    """InputError (naming ``source``) unless every layer lists the droplet masks of the first, by material and in
    its order: a slice's label m + 1 is the layer's mask m, coloured as :func:`palette` colours the first layer's
    (a layer whose masks were other materials, or in another order, would print in the wrong colours)."""
    def materials(entry: dict) -> list:
        return [str(channel.get("material")) for channel in entry.get("channels") or []]

    def listed(names: list) -> str:
        return f"({', '.join(names)})" if names else "none"

    layers = manifest["layers"]
    first = materials(layers[0]) if layers else []
    for entry in layers[1:]:
        if materials(entry) != first:
            raise InputError(f"{source}: layer {entry.get('index')} has droplet masks {listed(materials(entry))}, the "
                             f"first layer {listed(first)}; voxel-print colours every layer's masks as the first "
                             "layer's")


def sample_indices(count: int, step: float, new_step: float, new_count: int) -> np.ndarray:
    """Index of the source cell (size ``step``) holding the centre of each of ``new_count`` cells of size
    ``new_step`` laid from the same origin: (new_count,) int, clipped to 0..count-1."""
    centres = (np.arange(new_count) + 0.5) * new_step
    return np.clip(np.floor(centres / step).astype(np.int64), 0, count - 1)


def labels_of(planes: list[Bits], width: int, rows: np.ndarray | None = None,
              columns: np.ndarray | None = None) -> np.ndarray:
    """(h, w) uint8 material label of each pixel of a layer given as the packed rows of its label ``planes``
    (its droplet masks, or its solid pixels alone): 0 empty, m + 1 plane m (the last plane holding a pixel,
    were two to hold it); only the pixels at ``rows`` x ``columns`` (index arrays, default all) when given,
    only the sampled rows unpacked."""
    labels = None
    for number, bits in enumerate(planes, 1):
        packed = bits.rows if rows is None else np.take(bits.rows, rows, axis=0)
        plane = np.unpackbits(packed, axis=1, count=width)
        if number > 1:
            plane *= np.uint8(number)
        labels = plane if labels is None else np.maximum(labels, plane, out=labels)
    if columns is None or np.array_equal(columns, np.arange(width)):
        return labels
    return np.take(labels, columns, axis=1)


def label_planes(solid: Bits, masks: list[Bits]) -> list[Bits]:
    """The planes a layer's labels come from: its droplet masks, or its solid pixels without them."""
    return masks or [solid]


#: :func:`run_stream_limit`: a slice's image data is written from its runs when that takes at most 1/256 of its
#: scanlines' bytes and 8 bytes a row, and 1 KB (sizes measured in benchmarks/README.md).
RUN_STREAM_SHARE, RUN_STREAM_ROW_BYTES = 256, 8

#: Most label planes :func:`slice_scanlines` colours a packed byte of at once: a table of 256 ** planes entries of
#: 8 pixels each (2 planes: 65,536 x 24 bytes in RGB).
MOST_TABLE_PLANES = 2


@functools.lru_cache(maxsize=4)
def _byte_colours(colours: bytes, samples: int, planes: int) -> np.ndarray:
    """(256 ** planes,) table of the colours of the 8 pixels of one packed byte of each of ``planes`` label
    planes (key: plane m's byte << 8 m), each entry 8 x ``samples`` bytes; the labels are :func:`labels_of`'s."""
    keys = np.arange(256 ** planes)
    labels = np.zeros((len(keys), 8), dtype=np.uint8)
    for number in range(planes):
        bits = np.unpackbits((keys >> (8 * number)).astype(np.uint8)[:, None], axis=1)
        labels = np.where(bits == 1, np.uint8(number + 1), labels)
    table = np.frombuffer(colours, dtype=np.uint8).reshape(-1, samples)[labels]
    return np.ascontiguousarray(table.reshape(len(keys), 8 * samples)).view(f"V{8 * samples}").ravel()


def slice_scanlines(planes: list[Bits], width: int, rows: np.ndarray, columns: np.ndarray,
                    colours: np.ndarray) -> np.ndarray:
    """(len(rows), 1 + len(columns) x samples) uint8 PNG scanlines (:func:`heoslice.pngfile.scanlines_png`,
    filter byte 0): the colour (``colours`` (n, samples), label k in row k) of each sampled pixel of a layer's
    label ``planes`` (:func:`labels_of`'s labels). Where the columns are the layer's own and there are at
    most MOST_TABLE_PLANES planes, each packed byte is coloured at once through a table
    (:func:`_byte_colours`), and the rows off the part are the background's."""
    samples = colours.shape[1]
    out = np.empty((len(rows), 1 + len(columns) * samples), dtype=np.uint8)
    out[:, 0] = 0
    if len(planes) > MOST_TABLE_PLANES or not np.array_equal(columns, np.arange(width)):
        out[:, 1:] = colours[labels_of(planes, width, rows, columns)].reshape(len(rows), -1)
        return out
    first, stop = min(bits.span[0] for bits in planes), max(bits.span[1] for bits in planes)
    inside = (rows >= first) & (rows < stop)
    out[~inside, 1:] = np.broadcast_to(colours[0], (width, samples)).reshape(-1)
    if inside.any():
        sampled = rows[inside]
        keys = np.take(planes[0].rows, sampled, axis=0).astype(np.uint16 if len(planes) > 1 else np.uint8)
        for number, bits in enumerate(planes[1:], 1):
            keys |= np.take(bits.rows, sampled, axis=0).astype(np.uint16) << np.uint16(8 * number)
        table = _byte_colours(np.ascontiguousarray(colours, dtype=np.uint8).tobytes(), samples, len(planes))
        out[inside, 1:] = np.take(table, keys).view(np.uint8).reshape(len(sampled), -1)[:, :width * samples]
    return out


def slice_png(planes: list[Bits], width: int, rows: np.ndarray, columns: np.ndarray, colours: np.ndarray,
              dpi: tuple[float, float]) -> bytes:
    """The RGB PNG of a Voxel Print slice taken from a layer's label ``planes`` (sampled at ``rows`` x ``columns``,
    label k coloured ``colours[k]``, (labels, 3) uint8): its image data written from the rows' runs of one colour
    (:func:`run_stream`) when that stream is short (:func:`run_stream_limit`), else its scanlines coloured
    (:func:`slice_scanlines`) and deflated by zlib-ng."""
    code = run_code(frozenset({0, *np.asarray(colours, dtype=np.uint8).ravel().tolist()}), 3)
    data = run_stream(planes, width, rows, columns, colours, code, run_stream_limit(len(columns), len(rows)))
    if data is None:
        return scanlines_png(slice_scanlines(planes, width, rows, columns, colours), len(columns), colours.shape[1],
                             8, dpi)
    return deflated_png(data, len(columns), len(rows), colours.shape[1], 8, dpi)


def run_stream_limit(width: int, height: int) -> int:
    """Longest image data (bytes) :func:`slice_png` writes from runs for a ``width`` x ``height`` px slice:
    1 / RUN_STREAM_SHARE of its RGB scanlines' bytes, RUN_STREAM_ROW_BYTES a row and 1 KB. A longer stream is a
    layer of short runs (a dithered grading), which zlib-ng deflates smaller, finding its repeats."""
    return height * (1 + 3 * width) // RUN_STREAM_SHARE + RUN_STREAM_ROW_BYTES * height + 1024


def printer_grid(manifest: dict, dpi: tuple[float, float], pitch: float) -> tuple:
    """The printer's grid over the stack: (width, height, slices, columns, rows, sources), the slice images'
    size in px at ``dpi``, their count at ``pitch`` mm, and which stack column (width,), row (height,) and layer
    (slices,) each of their pixels and slices samples (:func:`sample_indices`); InputError past the export's
    bounds."""
    image, (px, py), h = manifest["image"], manifest["pixel_size_mm"], manifest["layer_height_mm"]
    new_px, new_py = 25.4 / dpi[0], 25.4 / dpi[1]
    width, height = max(1, round(image["width"] * px / new_px)), max(1, round(image["height"] * py / new_py))
    z_min, z_max = manifest["z_range_mm"]
    slices = max(1, int(np.ceil((z_max - z_min) / pitch - 1e-9)))
    if width * height > MAX_IMAGE_PIXELS or slices > 4 * MAX_LAYERS:
        raise InputError(f"dpi: {slices} slices of {width} x {height} px at {dpi[0]:g} x {dpi[1]:g} dpi and "
                         f"{pitch:g} mm is more than an export writes")
    return (width, height, slices, sample_indices(image["width"], px, new_px, width),
            sample_indices(image["height"], py, new_py, height),
            sample_indices(len(manifest["layers"]), h, pitch, slices))


def source_runs(sources: np.ndarray) -> list[tuple[int, int, int]]:
    """(stack layer, first slice, stop slice) of each run of consecutive slices sampling the same stack layer
    (``sources`` from :func:`printer_grid`): a layer coarser than the pitch gives several identical slices,
    each run encoded once."""
    starts = np.flatnonzero(np.diff(sources, prepend=-1) != 0)
    stops = np.append(starts[1:], len(sources))
    return list(zip(sources[starts].tolist(), starts.tolist(), stops.tolist()))


def write(stack: StackPlan, sink: Sink, options: ExportOptions) -> dict:
    """Write the slices and ``voxelprint.json`` (materials, colours, resolution, pitch). Every layer is checked
    as it is read (:func:`heoslice.stack.verify.verified_layer`), over the cores; each run of slices sampling one
    layer is encoded once."""
    directory, manifest = stack.directory, stack.manifest
    dpi = options.dpi or DEFAULT_DPI
    pitch = options.pitch_mm or DEFAULT_PITCH_MM
    background = tuple(options.background or DEFAULT_BACKGROUND)
    check_printable(manifest, directory)
    check_same_masks(manifest, Path(directory) / MANIFEST)
    materials = palette(manifest, background, Path(directory) / MANIFEST)
    width, height, slices, columns, rows, sources = printer_grid(manifest, dpi, pitch)
    colours = np.array([background] + [colour for _, colour in materials], dtype=np.uint8)
    runs = {layer: (start, stop) for layer, start, stop in source_runs(sources)}
    image_width = manifest["image"]["width"]

    def encoded(index: int) -> bytes | None:
        planes = label_planes(*verified_layer(stack, index))
        return slice_png(planes, image_width, rows, columns, colours, dpi) if index in runs else None

    total = len(manifest["layers"])
    for index, data in enumerate(ordered_map(encoded, range(total))):
        if data is not None:
            for number in range(*runs[index]):
                sink.add(f"slice_{number:05d}.png", data)
        sink.progress(index + 1, total)
    summary = {"format": "voxel-print", "slices": slices, "width": width, "height": height, "dpi": list(dpi),
               "pitch_mm": pitch, "background": list(background),
               "materials": [{"name": name, "color": list(colour)} for name, colour in materials],
               "source": {"layers": len(manifest["layers"]), "layer_height_mm": manifest["layer_height_mm"],
                          "dpi": manifest["dpi"]}}
    sink.add(SUMMARY_FILE, (json.dumps(summary, indent=1) + "\n").encode())
    return summary


FORMAT = ExportFormat("voxel-print", "GrabCAD Voxel Print slices (Stratasys PolyJet): one RGB PNG per layer, "
                      "one colour per material, 600 x 300 dpi at 0.027 mm by default", write)
