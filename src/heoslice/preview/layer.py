"""One layer of a stack as a display image, in material colours or dark solid on white.

RGBA layers are shown in their material colours over dark grey (so a white or light
material stays visible). Layers with droplet masks (a multi-material stack) are shown the
same way, composed from the masks: each set pixel of a material's mask in that
material's display colour (``grading.materials[].color``). Other 1-bit layers are dark
solid on white. Large layers are reduced (box filter) to fit the requested size, so
in a reduced preview a dithered mix of droplets shows as its blended colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from heoslice.errors import InputError, VerifyError, shown
from heoslice.stack import MANIFEST, layer_strips, read_manifest

#: Longest side of a drawn preview, px: larger requests are refused, larger layers reduced to it
#: (memory: at most about 4 x MAX_PREVIEW_SIDE^2 x 3 bytes for the image being reduced).
MAX_PREVIEW_SIDE = 4096
MIN_PREVIEW_SIDE = 16
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


def channel_colors(manifest: dict, index: int, source: str | Path = MANIFEST) -> np.ndarray:
    """(k, 3) uint8 display colours of layer ``index``'s droplet masks, looked up by material name in
    ``grading.materials``; VerifyError, naming the manifest file ``source``, when a material has no valid
    colour there."""
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
            raise VerifyError(f"{source}: layer {index}: droplet mask material {channel.get('material')!r} has "
                              "no [r, g, b] colour in grading.materials")
        colors.append(color)
    return np.array(colors, dtype=np.uint8).reshape(-1, 3)


class BoxReducer:
    """Box-filter reduction by an integer ``factor`` of an image fed as row strips of C feature planes
    ((rows, w) each, any real dtype), drawn as (ceil(h / factor), ceil(w / factor), 3) uint8 by ``to_rgb``
    (block means (r, w', C) float32 -> (r, w', 3) uint8). The display colour is linear in the features,
    so the mean colour of a block is ``to_rgb`` of its mean features. Memory: the drawn image and fewer
    than ``factor`` rows of the planes."""

    def __init__(self, width: int, height: int, factor: int, to_rgb):
        self.factor, self.to_rgb = factor, to_rgb
        self.out = np.empty((-(-height // factor), -(-width // factor), 3), dtype=np.uint8)
        self._carry: list[np.ndarray] | None = None
        self._row = 0
        self._columns = np.arange(0, width, factor)
        self._column_counts = np.diff(np.append(self._columns, width)).astype(np.float32)

    def feed(self, planes: list[np.ndarray]) -> None:
        """Add the next rows of the image: one (rows, w) array per feature."""
        if self._carry is not None:
            planes = [np.concatenate([carry, plane]) for carry, plane in zip(self._carry, planes)]
        rows = len(planes[0])
        whole = rows // self.factor * self.factor
        if whole:
            self._emit([plane[:whole] for plane in planes])
        self._carry = [plane[whole:] for plane in planes] if whole < rows else None

    def finish(self) -> np.ndarray:
        """The drawn image, after the last rows were fed."""
        if self._carry is not None:
            self._emit(self._carry)
            self._carry = None
        return self.out

    def _emit(self, planes: list[np.ndarray]) -> None:
        if self.factor == 1:
            means = np.stack([plane.astype(np.float32) for plane in planes], axis=-1)
        else:
            starts = np.arange(0, len(planes[0]), self.factor)
            counts = np.diff(np.append(starts, len(planes[0]))).astype(np.float32)[:, None] * self._column_counts
            means = np.stack([np.add.reduceat(np.add.reduceat(plane, starts, axis=0, dtype=np.float32),
                                              self._columns, axis=1) / counts for plane in planes], axis=-1)
        self.out[self._row:self._row + len(means)] = self.to_rgb(means)
        self._row += len(means)


def _rgb(values: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def _display(kind: str, colors: np.ndarray | None):
    """``to_rgb`` of a layer kind: block means of its features -> display colour (see :func:`_planes`)."""
    solid, background = np.asarray(SOLID_GREY, np.float32), np.asarray(BACKGROUND, np.float32)
    dark = np.asarray(RGBA_BACKGROUND, np.float32)
    if kind == "bilevel":
        return lambda m: _rgb(background + (solid - background) * m)
    if kind == "rgb":
        return _rgb
    if kind == "rgba":
        return lambda m: _rgb(m[..., :3] + dark * (1.0 - m[..., 3:4]))
    palette = np.asarray(colors, np.float32)
    return lambda m: _rgb(m @ palette + dark * (1.0 - m.sum(axis=-1, keepdims=True)))


def _planes(kind: str, pixels: np.ndarray, masks: list[np.ndarray], index: int, alpha: bool) -> list[np.ndarray]:
    """The feature planes of one strip ((rows, w) each), linear in the display colour: solid (bilevel),
    R, G, B (rgb), alpha-premultiplied R, G, B and alpha in 0..1 (rgba), or one plane per droplet mask
    (channels, checked to cover exactly the strip's solid pixels once each)."""
    if kind == "bilevel":
        return [pixels[:, :, 0] != 0]
    if kind == "rgb":
        return [pixels[:, :, c] for c in range(3)]
    if kind == "rgba":
        weight = pixels[:, :, 3].astype(np.float32) / 255.0
        return [pixels[:, :, c] * weight for c in range(3)] + [weight]
    solid = pixels[:, :, 3] > 0 if alpha and pixels.shape[2] == 4 else np.any(pixels != 0, axis=2)
    planes = [mask[:, :, 0] != 0 for mask in masks]
    covered = np.zeros(solid.shape, dtype=np.uint16)
    for plane in planes:
        covered += plane
    if not np.array_equal(covered, solid):
        raise VerifyError(f"layer {index}: the droplet masks do not cover exactly the layer's solid pixels "
                          "once each")
    return planes


def layer_display(directory: Path, manifest: dict, index: int, factor: int = 1) -> np.ndarray:
    """(ceil(h / factor), ceil(w / factor), 3) uint8 display image of layer ``index``, reduced while it is
    decoded (box filter): from its droplet masks when it has them, else from its stored pixels.
    Memory: the reduced image and one strip of each file."""
    with_channels = bool(manifest["layers"][index].get("channels"))
    colors = channel_colors(manifest, index, Path(directory) / MANIFEST) if with_channels else None
    image = manifest["image"]
    samples = {"1": "bilevel", "L": "bilevel", "RGB": "rgb", "RGBA": "rgba"}[image.get("mode", "1")]
    kind = "channels" if with_channels else samples
    reducer = BoxReducer(image["width"], image["height"], factor, _display(kind, colors))
    alpha = manifest["mask"] == "alpha"
    for _, pixels, masks in layer_strips(directory, manifest, index, channels=with_channels):
        reducer.feed(_planes(kind, pixels, masks, index, alpha))
    return reducer.finish()


def fit(image, size: int | None):
    """A PIL image reduced (box filter) so that its longer side is at most ``size`` pixels."""
    from PIL import Image

    if size is None or max(image.size) <= size:
        return image
    scale = size / max(image.size)
    target = (max(1, round(image.size[0] * scale)), max(1, round(image.size[1] * scale)))
    return image.resize(target, Image.Resampling.BOX)


def check_size(size: int | None, what: str = "size") -> int:
    """The longest side a preview is drawn at: ``size`` (16 .. MAX_PREVIEW_SIDE) or MAX_PREVIEW_SIDE when None."""
    if size is None:
        return MAX_PREVIEW_SIDE
    if not (isinstance(size, int) and MIN_PREVIEW_SIDE <= size <= MAX_PREVIEW_SIDE):
        raise InputError(f"{what}: must be an integer from {MIN_PREVIEW_SIDE} to {MAX_PREVIEW_SIDE} px, "
                         f"not {shown(size)}"[:200])
    return size


def layer_image(directory: Path, index: int, size: int | None = None, manifest: dict | None = None):
    """PIL RGB image of one layer of a stack, its longer side reduced to ``size`` pixels (at most
    MAX_PREVIEW_SIDE; the full layer when it fits). The layer is decimated by an integer factor while it
    is decoded, then box-filtered to the exact size, so memory follows the drawn size, not the layer's."""
    from PIL import Image

    size = check_size(size)
    manifest = read_manifest(Path(directory)) if manifest is None else manifest
    count = len(manifest["layers"])
    if not 0 <= index < count:
        raise InputError(f"layer: layer {index} does not exist (the stack has layers 0..{count - 1})")
    longest = max(manifest["image"]["width"], manifest["image"]["height"])
    factor = max(1, longest // size)
    return fit(true_aspect(Image.fromarray(layer_display(Path(directory), manifest, index, factor)), manifest), size)


def true_aspect(image, manifest: dict):
    """A layer's PIL image (on the stack's pixel grid) stretched to its true aspect in mm where the pixels are not
    square (``--dpi 600x300``): the coarser axis's pixels repeated (nearest), so a round part draws round."""
    from PIL import Image

    px, py = manifest["pixel_size_mm"]
    if abs(px - py) <= 1e-9 * max(px, py):
        return image
    width, height = image.size
    stretched = (round(width * px / py), height) if px > py else (width, round(height * py / px))
    return image.resize(stretched, Image.Resampling.NEAREST)


def annotated_layer_image(directory: Path, index: int, size: int | None = None, manifest: dict | None = None):
    """:func:`layer_image` with a footer (:func:`heoslice.preview.annotate.annotate`): the layer's number and z,
    the legend of the stack's materials in their display colours and a scale bar in mm. The layer keeps its
    place and size at the top left; the footer adds height (and width, below MIN_FOOTER_WIDTH px)."""
    from heoslice.preview.annotate import annotate, legend_of

    manifest = read_manifest(Path(directory)) if manifest is None else manifest
    image = layer_image(directory, index, size, manifest)
    px_per_mm = image.size[0] / (manifest["image"]["width"] * manifest["pixel_size_mm"][0])
    count, z = len(manifest["layers"]), manifest["layers"][index]["z_mm"]
    return annotate(image, f"layer {index} (of 0..{count - 1}), z {z:.3f} mm", legend_of(manifest, SOLID_GREY), px_per_mm)
