"""``png``: every layer image (and droplet mask) of the stack as a PNG of the same size, with the stack's
``manifest.json`` beside them, for DIY and RIP pipelines that take plain PNG stacks (folder or zip)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from heoslice.export.base import ExportFormat, ExportOptions, Sink
from heoslice.stack import MANIFEST, read_layer_channels, read_layer_pixels, resolve_inside


def png_bytes(pixels: np.ndarray, dpi: tuple[float, float]) -> bytes:
    """PNG of stored layer pixels: (h, w) bool as 1-bit with solid black on white (as the TIFFs show and
    ``preview`` draws them), (h, w, 4) uint8 as RGBA; the dpi in the pHYs chunk."""
    from PIL import Image

    image = Image.fromarray(~pixels.astype(bool)) if pixels.ndim == 2 else Image.fromarray(pixels, "RGBA")
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", dpi=(round(dpi[0]), round(dpi[1])))
    return buffer.getvalue()


def write(directory: Path, manifest: dict, sink: Sink, options: ExportOptions) -> dict:
    """Write ``layer_NNNNN.png`` (and ``layer_NNNNN_MATERIAL.png``) per layer and the manifest, bottom first."""
    dpi = tuple(manifest["dpi"])
    for entry in manifest["layers"]:
        index = entry["index"]
        pixels = read_layer_pixels(directory, manifest, index)
        sink.add(Path(entry["file"]).with_suffix(".png").name, png_bytes(pixels, dpi))
        for channel, mask in zip(entry.get("channels", []), read_layer_channels(directory, manifest, index)):
            sink.add(Path(channel["file"]).with_suffix(".png").name, png_bytes(mask, dpi))
    sink.add(MANIFEST, resolve_inside(directory, MANIFEST).read_bytes())
    return {"layers": len(manifest["layers"]), "dpi": list(dpi), "layer_height_mm": manifest["layer_height_mm"]}


FORMAT = ExportFormat("png", "one PNG per layer image and droplet mask at the stack's resolution, manifest "
                      "beside them", write)
