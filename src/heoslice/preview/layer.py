"""One layer of a stack as a display image, in material colours or dark solid on white.

RGBA layers are shown in their material colours over dark grey (so a white or light
material stays visible). Layers with droplet masks (``slice --channels``) are shown the
same way, composed from the masks: each set pixel of a material's mask in that
material's display colour (``grading.materials[].color``). Other 1-bit layers are dark
solid on white. Large layers are reduced (box filter) to fit the requested size, so
in a reduced preview a dithered mix of droplets shows as its blended colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from heoslice.errors import InputError, VerifyError
from heoslice.stack import read_layer_channels, read_layer_mask, read_layer_pixels, read_manifest

#: Colour of solid pixels in 1-bit layers.
SOLID_GREY = (64, 64, 64)
BACKGROUND = (255, 255, 255)
#: Empty pixels behind RGBA layers: dark, since material colours are often white or light.
RGBA_BACKGROUND = (32, 32, 32)


def layer_rgb(pixels: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 display image of stored layer pixels ((h, w) bool/uint8 or (h, w, 4) RGBA)."""
    if pixels.ndim == 2:
        solid = pixels != 0
        out = np.empty((*solid.shape, 3), dtype=np.uint8)
        out[...] = BACKGROUND
        out[solid] = SOLID_GREY
        return out
    rgb = pixels[..., :3].astype(np.uint16)
    alpha = pixels[..., 3:4].astype(np.uint16)
    background = np.asarray(RGBA_BACKGROUND, dtype=np.uint16)
    return ((rgb * alpha + background * (255 - alpha) + 127) // 255).astype(np.uint8)


def channels_rgb(masks: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 display image of droplet masks ((k, h, w) bool): each set pixel of mask m in
    ``colors[m]`` ((k, 3) uint8), pixels in no mask dark grey as behind RGBA layers."""
    out = np.empty((*masks.shape[1:], 3), dtype=np.uint8)
    out[...] = RGBA_BACKGROUND
    for mask, color in zip(masks, np.asarray(colors, dtype=np.uint8)):
        out[mask] = color
    return out


def channel_colors(manifest: dict, index: int) -> np.ndarray:
    """(k, 3) uint8 display colours of layer ``index``'s droplet masks, looked up by material name in
    ``grading.materials``; VerifyError when a material has no valid colour there."""
    grading = manifest.get("grading")
    materials = grading.get("materials") if isinstance(grading, dict) else None
    known = {}
    for material in materials if isinstance(materials, list) else []:
        if isinstance(material, dict) and isinstance(material.get("name"), str):
            known.setdefault(material["name"], material.get("color"))
    colors = []
    for channel in manifest["layers"][index]["channels"]:
        color = known.get(channel.get("material"))
        if not (isinstance(color, list) and len(color) == 3
                and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 255 for v in color)):
            raise VerifyError(f"layer {index}: droplet mask material {channel.get('material')!r} has no "
                              "[r, g, b] colour in the manifest's grading.materials")
        colors.append(color)
    return np.array(colors, dtype=np.uint8).reshape(-1, 3)


def layer_display(directory: Path, manifest: dict, index: int) -> np.ndarray:
    """(h, w, 3) uint8 display image of layer ``index``: from its droplet masks when it has them
    (checked to cover exactly the layer's solid pixels, once each), else from its stored pixels."""
    if not manifest["layers"][index].get("channels"):
        return layer_rgb(read_layer_pixels(directory, manifest, index))
    colors = channel_colors(manifest, index)
    solid = read_layer_mask(directory, manifest, index)
    masks = read_layer_channels(directory, manifest, index)
    if not np.array_equal(masks.sum(axis=0, dtype=np.uint16), solid):
        raise VerifyError(f"layer {index}: the droplet masks do not cover exactly the layer's solid pixels "
                          "once each")
    return channels_rgb(masks, colors)


def fit(image, size: int | None):
    """A PIL image reduced (box filter) so that its longer side is at most ``size`` pixels."""
    from PIL import Image

    if size is None or max(image.size) <= size:
        return image
    scale = size / max(image.size)
    target = (max(1, round(image.size[0] * scale)), max(1, round(image.size[1] * scale)))
    return image.resize(target, Image.Resampling.BOX)


def layer_image(directory: Path, index: int, size: int | None = None, manifest: dict | None = None):
    """PIL RGB image of one layer of a stack, reduced to ``size`` pixels on its longer side."""
    from PIL import Image

    manifest = read_manifest(Path(directory)) if manifest is None else manifest
    count = len(manifest["layers"])
    if not 0 <= index < count:
        raise InputError(f"--layer: layer {index} does not exist (the stack has layers 0..{count - 1})")
    return fit(Image.fromarray(layer_display(Path(directory), manifest, index)), size)
