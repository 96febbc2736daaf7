"""``png``: every layer image (and droplet mask) of the stack as a PNG of the same size, with the stack's
``manifest.json`` beside them, for DIY and RIP pipelines that take plain PNG stacks (folder or zip)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from heoslice.export.base import ExportFormat, ExportOptions, Sink
from heoslice.pipeline.parallel import ordered_map
from heoslice.pngfile import bilevel_png, png_file
from heoslice.stack import MANIFEST, read_layer_channels, read_layer_pixels, resolve_inside
from heoslice.stack.verify import StackPlan, verified_layer

#: Image modes whose layers a PNG shows as 1-bit (solid or not), written from packed bits.
BILEVEL_MODES = ("1", "L")


def png_bytes(pixels: np.ndarray, dpi: tuple[float, float]) -> bytes:
    """PNG of stored layer pixels: (h, w) bool as 1-bit with solid black on white (as the TIFFs show and
    ``preview`` draws them), (h, w, 3 or 4) uint8 as RGB or RGBA; the dpi in the pHYs chunk."""
    if pixels.ndim == 2:
        return bilevel_png(np.packbits(pixels.astype(bool), axis=1), pixels.shape[1], dpi)
    height, width, samples = pixels.shape
    return png_file(np.ascontiguousarray(pixels, dtype=np.uint8).reshape(height, width * samples), width, samples,
                    8, dpi)


def layer_pngs(stack: StackPlan, index: int) -> list[tuple[str, bytes]]:
    """(name, PNG bytes) of layer ``index``'s image and its droplet masks, in that order, the layer checked as it
    is read (:func:`heoslice.stack.verify.verified_layer`): 1-bit layers from the bits that check decoded."""
    directory, manifest = stack.directory, stack.manifest
    entry, dpi = manifest["layers"][index], tuple(manifest["dpi"])
    names = [Path(record["file"]).with_suffix(".png").name for record in [entry, *entry.get("channels", [])]]
    solid, masks = verified_layer(stack, index)
    if manifest["image"].get("mode", "1") in BILEVEL_MODES:
        width = manifest["image"]["width"]
        return [(name, bilevel_png(bits.rows, width, dpi)) for name, bits in zip(names, [solid, *masks])]
    images = [read_layer_pixels(directory, manifest, index), *read_layer_channels(directory, manifest, index)]
    return [(name, png_bytes(pixels, dpi)) for name, pixels in zip(names, images)]


def write(stack: StackPlan, sink: Sink, options: ExportOptions) -> dict:
    """Write ``layer_NNNNN.png`` (and ``layer_NNNNN_MATERIAL.png``) per layer and the manifest, bottom first;
    the layers are checked, read and encoded over the cores (:func:`heoslice.pipeline.parallel.ordered_map`)."""
    manifest = stack.manifest
    dpi = tuple(manifest["dpi"])
    total = len(manifest["layers"])
    for done, files in enumerate(ordered_map(lambda index: layer_pngs(stack, index), range(total)), 1):
        for name, data in files:
            sink.add(name, data)
        sink.progress(done, total)
    sink.add(MANIFEST, resolve_inside(stack.directory, MANIFEST).read_bytes())
    return {"layers": len(manifest["layers"]), "dpi": list(dpi), "layer_height_mm": manifest["layer_height_mm"]}


FORMAT = ExportFormat("png", "one PNG per layer image and droplet mask at the stack's resolution, manifest "
                      "beside them", write, takes=frozenset())
