"""``gcvf``: a GrabCAD Voxel Print File (Stratasys PolyJet): one zip GrabCAD Print opens as it is.

The zip holds ``layer_0.png``, ``layer_1.png``, ... (numbered from 0 without padding, bottom first;
RGBA, one exact colour per material, empty pixels opaque black) and ``ConfigFile.xml``: the
resolution, the slice thickness in nanometres, the slice size and count, the bit depth, the most
colours, and per material its name, RGBA and voxel count (its pixels over every slice written).
The layers are resampled onto the printer grid as ``voxel-print`` does (nearest sample; an exact copy
for a stack sliced with the printer's preset, ``slice --printer``). Field names and layout follow the
public builders listed in ``docs/export-formats.md``. At most :data:`MAX_MATERIALS` materials.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from heoslice.errors import InputError
from heoslice.export.base import ExportFormat, ExportOptions, Sink
from heoslice.export.voxel_print import (
    DEFAULT_DPI,
    DEFAULT_PITCH_MM,
    label_planes,
    labels_of,
    palette,
    printer_grid,
    source_runs,
)
from heoslice.pipeline.parallel import ordered_map
from heoslice.pngfile import labels_png
from heoslice.stack import MANIFEST, check_printable
from heoslice.stack.verify import StackPlan, verified_layer

#: Most model materials one .gcvf carries (its ConfigFile's MaxNumberOfColors).
MAX_MATERIALS = 6
#: ConfigFile.xml's format version and bit depth, as the public builders write them.
CONFIG_VERSION = 2
BIT_DEPTH = 4
BACKGROUND_RGBA = (0, 0, 0, 255)
CONFIG_FILE = "ConfigFile.xml"


def config_xml(materials: list[tuple[str, tuple[int, int, int]]], counts: list[int], dpi: tuple[float, float],
               pitch_mm: float, size: tuple[int, int], slices: int) -> bytes:
    """The ``ConfigFile.xml`` of a .gcvf: materials (name, RGB) with their voxel counts, resolution (dpi x, y),
    slice thickness (mm, written in nanometres), slice size (width, height px) and count."""
    rows = "\n".join(
        f"        <Material>\n            <Name>{escape(name)}</Name>\n"
        f"            <RGBA>{' '.join(str(v) for v in (*colour, 255))}</RGBA>\n"
        f"            <VoxelCount>{count}</VoxelCount>\n        </Material>"
        for (name, colour), count in zip(materials, counts))
    text = f"""<?xml version="1.0" encoding="UTF-8"?>
<GCVF>
    <Version>{CONFIG_VERSION}</Version>
    <Resolution>
        <XDpi>{round(dpi[0])}</XDpi>
        <YDpi>{round(dpi[1])}</YDpi>
        <SliceThicknessNanoMeter>{round(pitch_mm * 1e6)}</SliceThicknessNanoMeter>
    </Resolution>
    <SliceDimensions>
        <SliceWidth>{size[0]}</SliceWidth>
        <SliceHeight>{size[1]}</SliceHeight>
    </SliceDimensions>
    <SliceRange>
        <StartIndex>0</StartIndex>
        <NumberOfSlices>{slices}</NumberOfSlices>
    </SliceRange>
    <BitDepth>{BIT_DEPTH}</BitDepth>
    <MaxNumberOfColors>{MAX_MATERIALS}</MaxNumberOfColors>
    <DataSemantics>Materials</DataSemantics>
    <CreationMode>MODEL_ONLY</CreationMode>
    <ImageFilePrefix>layer_</ImageFilePrefix>
    <MaterialList>
        <BackGroundMaterialRGBA>{' '.join(str(v) for v in BACKGROUND_RGBA)}</BackGroundMaterialRGBA>
{rows}
    </MaterialList>
</GCVF>
"""
    return text.encode("utf-8")


def write(stack: StackPlan, sink: Sink, options: ExportOptions) -> dict:
    """Write the layers and ``ConfigFile.xml`` into the .gcvf zip; every layer is checked as it is read
    (:func:`heoslice.stack.verify.verified_layer`), over the cores, each run of slices sampling it encoded once."""
    directory, manifest = stack.directory, stack.manifest
    if not sink.is_zip:
        raise InputError(f"format: a .gcvf is one zip file; name the output {sink.target.name}.gcvf")
    if options.background is not None:
        raise InputError("background: a .gcvf's empty voxels are black (its BackGroundMaterialRGBA)")
    dpi = options.dpi or DEFAULT_DPI
    pitch = options.pitch_mm or DEFAULT_PITCH_MM
    check_printable(manifest, directory)
    materials = palette(manifest, BACKGROUND_RGBA[:3], Path(directory) / MANIFEST)
    if len(materials) > MAX_MATERIALS:
        raise InputError(f"format: a .gcvf carries at most {MAX_MATERIALS} materials; this stack has "
                         f"{len(materials)} ({', '.join(name for name, _ in materials)})")
    width, height, slices, columns, rows, sources = printer_grid(manifest, dpi, pitch)
    colours = np.array([BACKGROUND_RGBA] + [(*colour, 255) for _, colour in materials], dtype=np.uint8)

    runs = {layer: (start, stop) for layer, start, stop in source_runs(sources)}
    image_width = manifest["image"]["width"]

    def encoded(index: int) -> tuple[bytes, np.ndarray] | None:
        planes = label_planes(*verified_layer(stack, index))
        if index not in runs:
            return None
        labels = labels_of(planes, image_width, rows, columns)
        return labels_png(labels, colours, dpi), np.bincount(labels.ravel(), minlength=len(colours))

    counts = np.zeros(len(materials) + 1, dtype=np.int64)
    total = len(manifest["layers"])
    for index, done in enumerate(ordered_map(encoded, range(total))):
        if done is not None:
            data, found = done
            start, stop = runs[index]
            for number in range(start, stop):
                sink.add(f"layer_{number}.png", data)
            counts += found * (stop - start)
        sink.progress(index + 1, total)
    sink.add(CONFIG_FILE, config_xml(materials, counts[1:].tolist(), dpi, pitch, (width, height), slices))
    return {"format": "gcvf", "slices": slices, "width": width, "height": height, "dpi": list(dpi), "pitch_mm": pitch,
            "materials": [{"name": name, "rgba": [*colour, 255], "voxels": int(count)}
                          for (name, colour), count in zip(materials, counts[1:])]}


FORMAT = ExportFormat("gcvf", "GrabCAD Voxel Print File (Stratasys PolyJet): one zip of layer_N.png and "
                      "ConfigFile.xml, at most 6 materials, 600 x 300 dpi at 0.027 mm by default", write)
