"""``voxel-print``: a GrabCAD Voxel Print slice folder for Stratasys PolyJet printers (J-series).

Conventions (``docs/export-formats.md``): one RGB PNG per printer layer, all the same size, named
``slice_NNNNN.png`` bottom first; each material one exact colour (its ``grading.materials`` colour,
or white for a one-material stack), empty pixels the background colour (default black); 600 x 300 dpi
at a 0.027 mm pitch (the J750's high-mix mode) unless asked otherwise. The stack is resampled by
nearest sample, never blended, so every printed voxel keeps exactly one material: in the plane each
slice pixel takes the stack pixel under its centre, in z each slice the stack layer holding its
centre height. Refused: stacks that cannot print (:mod:`heoslice.stack.printable`: RGBA previews sliced
with ``--rgba``, every layer empty), materials without a colour, two materials of one colour or one of
the background's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.export.base import ExportFormat, ExportOptions, Sink
from heoslice.pipeline.parallel import ordered_map
from heoslice.pngfile import labels_png
from heoslice.stack import MANIFEST, MAX_IMAGE_PIXELS, MAX_LAYERS, check_printable
from heoslice.stack.packed import layer_bits

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
            raise InputError(f"background: material {name!r} has colour {list(colour)}, the same as {seen[colour]}; "
                             "Voxel Print tells materials apart by colour (choose another --background)")
        seen[colour] = f"material {name!r}"
    return materials


def sample_indices(count: int, step: float, new_step: float, new_count: int) -> np.ndarray:
    """Index of the source cell (size ``step``) holding the centre of each of ``new_count`` cells of size
    ``new_step`` laid from the same origin: (new_count,) int, clipped to 0..count-1."""
    centres = (np.arange(new_count) + 0.5) * new_step
    return np.clip(np.floor(centres / step).astype(np.int64), 0, count - 1)


def layer_labels(directory: Path, manifest: dict, index: int, rows: np.ndarray | None = None,
                 columns: np.ndarray | None = None) -> np.ndarray:
    """(h, w) uint8 material label of each pixel of a stack layer: 0 empty, m + 1 material m (the last mask
    holding a pixel, were two to hold it); only the pixels at ``rows`` x ``columns`` (index arrays, default
    all) when given. Each file is read once, as packed bits, and only the sampled rows are unpacked."""
    image = manifest["image"]
    with_masks = bool(manifest["layers"][index].get("channels"))
    solid, masks = layer_bits(directory, manifest, index, solid=not with_masks)
    labels = None
    for number, bits in enumerate(masks if with_masks else [solid], 1):
        packed = bits.rows if rows is None else np.take(bits.rows, rows, axis=0)
        plane = np.unpackbits(packed, axis=1, count=image["width"])
        if number > 1:
            plane *= np.uint8(number)
        labels = plane if labels is None else np.maximum(labels, plane, out=labels)
    if columns is None or np.array_equal(columns, np.arange(image["width"])):
        return labels
    return np.take(labels, columns, axis=1)


def slice_png(directory: Path, manifest: dict, index: int, rows: np.ndarray, columns: np.ndarray,
              colours: np.ndarray, dpi: tuple[float, float]) -> bytes:
    """The PNG of a Voxel Print slice taken from stack layer ``index`` (sampled at ``rows`` x ``columns``)."""
    return labels_png(layer_labels(directory, manifest, index, rows, columns), colours, dpi)


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


def write(directory: Path, manifest: dict, sink: Sink, options: ExportOptions) -> dict:
    """Write the slices and ``voxelprint.json`` (materials, colours, resolution, pitch)."""
    dpi = options.dpi or DEFAULT_DPI
    pitch = options.pitch_mm or DEFAULT_PITCH_MM
    background = tuple(options.background or DEFAULT_BACKGROUND)
    check_printable(manifest, directory)
    materials = palette(manifest, background, Path(directory) / MANIFEST)
    width, height, slices, columns, rows, sources = printer_grid(manifest, dpi, pitch)
    colours = np.array([background] + [colour for _, colour in materials], dtype=np.uint8)
    runs = source_runs(sources)
    encoded = ordered_map(lambda layer: slice_png(directory, manifest, layer, rows, columns, colours, dpi),
                          [layer for layer, _, _ in runs])
    for data, (_, start, stop) in zip(encoded, runs):
        for number in range(start, stop):
            sink.add(f"slice_{number:05d}.png", data)
        sink.progress(stop, slices)
    summary = {"format": "voxel-print", "slices": slices, "width": width, "height": height, "dpi": list(dpi),
               "pitch_mm": pitch, "background": list(background),
               "materials": [{"name": name, "color": list(colour)} for name, colour in materials],
               "source": {"layers": len(manifest["layers"]), "layer_height_mm": manifest["layer_height_mm"],
                          "dpi": manifest["dpi"]}}
    sink.add(SUMMARY_FILE, (json.dumps(summary, indent=1) + "\n").encode())
    return summary


FORMAT = ExportFormat("voxel-print", "GrabCAD Voxel Print slices (Stratasys PolyJet): one RGB PNG per layer, "
                      "one colour per material, 600 x 300 dpi at 0.027 mm by default", write)
