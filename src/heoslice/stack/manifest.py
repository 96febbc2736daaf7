"""The manifest schema, in one place: its fields, how the slicer builds it, how readers check it.

``build_manifest`` makes the ``manifest.json`` object of a new stack from typed records,
and checks what it built with the same :func:`manifest_problem` that every reader
applies to a parsed file, so a stack heoslice writes is one heoslice accepts. The
fields are documented in ``docs/stack-format.md``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from heoslice import __version__
from heoslice.errors import InputError, VerifyError
from heoslice.grading.halftone import DEFAULT_METHOD as DEFAULT_HALFTONE
from heoslice.grading.halftone import METHODS as HALFTONE_METHODS
from heoslice.material import MAX_CHANNEL, is_channel, shared_channel

FORMAT_NAME = "heoslice-stack"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
LAYER_PATTERN = re.compile(r"^layer_\d{5,}(_[A-Za-z0-9-]+)?\.tif$")
#: Largest manifest accepted, bytes; larger is refused before parsing (20 000 layers take about 4 MB).
MAX_MANIFEST_BYTES = 16 << 20
#: Most JSON objects and arrays a manifest may hold (counted before parsing; bounds the parser's memory).
MAX_MANIFEST_CONTAINERS = 1 << 18
#: Largest image accepted by readers and writers, pixels (a 1 m x 1 m plate at 600 dpi is 5.6e8).
MAX_IMAGE_PIXELS = 1 << 30
#: Manifest image modes -> (bits per sample, samples per pixel) of the layer TIFFs.
IMAGE_MODES = {"1": (1, 1), "L": (8, 1), "RGB": (8, 3), "RGBA": (8, 4)}
#: The image mode of every droplet mask (docs/stack-format.md): 1-bit, whatever the layers' mode.
MASK_MODE = "1"
#: Most layers one stack may have (a 500 mm part at 10 micrometre layers); fewer with droplet masks, whose
#: entries make each layer's manifest entry longer (see max_layer_count).
MAX_LAYERS = 50_000
#: Manifest bytes and containers kept for everything but the layer entries (header, grading, warnings).
HEADER_BYTES = 1 << 20
HEADER_CONTAINERS = 1 << 12
#: Image mode -> how its solid mask is read ("mask" field).
MASK_OF_MODE = {"1": "nonzero", "L": "nonzero", "RGB": "nonzero", "RGBA": "alpha"}


@dataclass(frozen=True, slots=True)
class ChannelRecord:
    """One droplet mask of a layer: its material's name, file name, SHA-256 and set pixel count."""

    material: str
    file: str
    sha256: str
    solid_pixels: int


@dataclass(frozen=True, slots=True)
class LayerRecord:
    """One written layer: plane height (mm), image SHA-256, solid pixels, whether its contours were
    closed by force, and its droplet masks (None: the stack has none)."""

    z_mm: float
    sha256: str
    solid_pixels: int
    open_contours: bool
    channels: tuple[ChannelRecord, ...] | None = None


@dataclass(frozen=True, slots=True)
class ImageRecord:
    """The layer images' geometry and encoding: size (px), top-left corner (mm), mode, compression."""

    width: int
    height: int
    origin_mm: tuple[float, float]
    mode: str
    compression: str


def layer_file_name(index: int, channel: str | None = None) -> str:
    """File name of layer ``index`` (and of one of its channels), e.g. 'layer_00042.tif'."""
    suffix = f"_{channel}" if channel else ""
    return f"layer_{index:05d}{suffix}.tif"


def check_image_size(width: int, height: int) -> None:
    """Refuse (InputError) a layer image larger than MAX_IMAGE_PIXELS, before anything is written."""
    if width * height > MAX_IMAGE_PIXELS:
        raise InputError(f"layer images of {width} x {height} pixels exceed the limit of {MAX_IMAGE_PIXELS} "
                         "pixels; lower --dpi or the canvas")


def max_layer_count(channel_materials: Sequence[str] = ()) -> int:
    """Most layers a stack whose layers have droplet masks of these materials can hold: MAX_LAYERS, or fewer
    where that many layer entries (at their longest) would not fit MAX_MANIFEST_BYTES or
    MAX_MANIFEST_CONTAINERS beside HEADER_BYTES and HEADER_CONTAINERS. The slicer checks its layer
    count against this before slicing, so every stack it writes is one the readers accept."""
    channels = tuple(ChannelRecord(name, layer_file_name(MAX_LAYERS, "x" * len(name)), "f" * 64, MAX_IMAGE_PIXELS)
                     for name in channel_materials) or None
    longest = LayerRecord(-1.2345678901234567e-300, "f" * 64, MAX_IMAGE_PIXELS, False, channels)
    one, two = ({"layers": [_layer_entry(MAX_LAYERS, longest)] * count} for count in (1, 2))
    entry_bytes = len(json.dumps(two, indent=1)) - len(json.dumps(one, indent=1))
    entry_containers = 1 + (1 + len(channels) if channels else 0)
    return min(MAX_LAYERS, (MAX_MANIFEST_BYTES - HEADER_BYTES) // entry_bytes,
               (MAX_MANIFEST_CONTAINERS - HEADER_CONTAINERS) // entry_containers)


def build_manifest(*, source_file: str, source_sha256: str, layer_height_mm: float, dpi: tuple[float, float],
                   pixel_size_mm: tuple[float, float], image: ImageRecord, z_range_mm: tuple[float, float],
                   warnings: Sequence[str], layers: Sequence[LayerRecord], grading: dict | None = None,
                   parts: Sequence[dict] | None = None, scale: float = 1.0, placement: dict | None = None,
                   labels: Sequence[dict] | None = None) -> dict:
    """The ``manifest.json`` object of a finished stack, checked by :func:`manifest_problem` before it is
    returned (a failure is a bug in the slicer, raised as ValueError). ``parts``: a multi-part job's parts
    (:func:`heoslice.pipeline.parts.parts_records`); ``scale``: the factor the source file's coordinates were
    multiplied by before slicing (``slice --scale``); ``placement`` and ``labels``: a volume's place in its
    scan's space and its printed labels (:mod:`heoslice.pipeline.volume_job`)."""
    manifest = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "complete": True,
        "created_by": f"heoslice {__version__}",
        "source": {"file": source_file, "sha256": source_sha256},
        "scale": float(scale),
        "layer_height_mm": layer_height_mm,
        "dpi": [float(dpi[0]), float(dpi[1])],
        "pixel_size_mm": [pixel_size_mm[0], pixel_size_mm[1]],
        "image": {"width": image.width, "height": image.height, "origin_mm": [image.origin_mm[0], image.origin_mm[1]],
                  "mode": image.mode, "compression": image.compression},
        "mask": MASK_OF_MODE[image.mode],
        "z_range_mm": [float(z_range_mm[0]), float(z_range_mm[1])],
        "warnings": list(warnings),
        "layers": [_layer_entry(index, layer) for index, layer in enumerate(layers)],
    }
    if grading is not None:
        manifest["grading"] = grading
    if parts is not None:
        manifest["parts"] = list(parts)
    if placement is not None:
        manifest["placement"] = placement
    if labels is not None:
        manifest["labels"] = list(labels)
    problem = manifest_problem(manifest)
    if problem:
        raise ValueError(f"the slicer built a manifest its readers refuse: {problem}")
    return manifest


def _layer_entry(index: int, layer: LayerRecord) -> dict:
    entry = {"index": index, "z_mm": float(layer.z_mm), "file": layer_file_name(index), "sha256": layer.sha256,
             "solid_pixels": int(layer.solid_pixels), "open_contours": bool(layer.open_contours)}
    if layer.channels is not None:
        entry["channels"] = [{"material": channel.material, "file": channel.file, "sha256": channel.sha256,
                              "solid_pixels": int(channel.solid_pixels)} for channel in layer.channels]
    return entry


def grading_summary(grade, halftone: str | None = None, interior: str | None = None,
                    design: dict | None = None) -> dict:
    """The manifest's ``grading`` object of a grading specification (``GradeSpec``): what the interiors
    were graded with, the materials of the droplet masks in the order of the layers' masks, and, for a stack
    with droplet masks, the ``halftone`` method that made them (:func:`halftone_record`); ``interior`` (``field``, ``contour`` or
    ``graded``: what a coloured model's solid got) and ``design`` (the model's recorded design,
    :meth:`heoslice.material.design.Design.record`) when given."""
    regions = grade.regions
    material = _material_record
    extra = {key: value for key, value in (("interior", interior), ("design", design)) if value is not None}
    if getattr(regions, "depth_from", "layer") != "layer":
        extra["depth_from"] = regions.depth_from
    return {**extra, **halftone_record(halftone),
        "function": None if grade.function is None else grade.function.describe(),
        "target": material(grade.target),
        "from": material(grade.start),
        "nozzle_mm": regions.nozzle_mm,
        "depth_mm": regions.depth_mm,
        "direction": regions.direction,
        "offsets": regions.count,
        "materials": [material(m) for m in grade.channel_materials()],
    }


def halftone_record(halftone: str | None) -> dict:
    """The ``grading.halftone`` field of a stack with droplet masks: the method, left out for ordered dither (or
    None): without the field a stack is ordered, as every stack made before there was a choice, and an ordered
    stack stays byte for byte what it was."""
    return {} if halftone in (None, DEFAULT_HALFTONE) else {"halftone": halftone}


def droplet_summary(materials, halftone: str | None = None) -> dict:
    """The manifest's ``grading`` object of an ungraded stack with droplet masks (a multi-part job, a volume's
    labels or curve): the fields of :func:`grading_summary`, without a function or sub-region layout (null), the
    ``halftone`` that made the masks (:func:`halftone_record`) and the droplet masks' materials in the order of
    the layers' masks."""
    return {**halftone_record(halftone), "function": None, "target": None, "from": None, "nozzle_mm": None, "depth_mm": None, "direction": None,
            "offsets": None, "materials": [_material_record(m) for m in materials]}


def _material_record(material) -> dict | None:
    """A material as the manifest records it: name, [r, g, b] display colour, printer channel (or null)."""
    return None if material is None else material.record()


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def _finite_float(text: str) -> float:
    value = float(text)
    if not np.isfinite(value):
        raise ValueError(f"number {text[:40]} is out of range")
    return value


def parse_manifest(raw: bytes, path) -> dict:
    """The manifest in ``raw`` (the bytes of ``path``, at most MAX_MANIFEST_BYTES) after its structural
    check; VerifyError naming ``path`` and the first problem otherwise."""
    if len(raw) > MAX_MANIFEST_BYTES:
        raise VerifyError(f"{path}: manifest is larger than {MAX_MANIFEST_BYTES} bytes")
    containers = raw.count(b"{") + raw.count(b"[")
    if containers > MAX_MANIFEST_CONTAINERS:
        raise VerifyError(f"{path}: manifest has {containers} objects and arrays, more than the "
                          f"{MAX_MANIFEST_CONTAINERS} a stack can need")
    try:
        manifest = json.loads(raw.decode("utf-8"), parse_constant=_refuse_constant, parse_float=_finite_float)
    except UnicodeDecodeError as err:
        raise VerifyError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})") from err
    except ValueError as err:  # JSONDecodeError, and the hooks' refusals
        raise VerifyError(f"{path}: not valid JSON ({' '.join(str(err).split())[:160]})") from err
    except RecursionError as err:
        raise VerifyError(f"{path}: JSON nested too deeply") from err
    problem = manifest_problem(manifest)
    if problem:
        raise VerifyError(f"{path}: {problem}")
    return manifest


def _show(value) -> str:
    """A manifest value for a message: its repr, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


#: A sha256 digest as the manifest writes it: 64 lower-case hex digits.
_SHA256_HEX = re.compile(r"[0-9a-f]{64}")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _file_entry_problem(entry, what: str, pixels: int) -> str | None:
    """Problem of one file reference ({file, sha256, [solid_pixels]}) in the manifest, or None."""
    if not isinstance(entry.get("file"), str) or not entry["file"]:
        return f"{what}: missing or malformed 'file'"
    digest = entry.get("sha256")
    if not (isinstance(digest, str) and _SHA256_HEX.fullmatch(digest)):
        return f"{what}: 'sha256' must be 64 lower-case hex digits"
    solid = entry.get("solid_pixels")
    if solid is not None and not (_is_int(solid) and 0 <= solid <= pixels):
        return f"{what}: 'solid_pixels' must be an integer from 0 to {pixels}"
    return None


def manifest_problem(manifest) -> str | None:
    """The first structural problem of a manifest object (parsed or just built), or None."""
    if not isinstance(manifest, dict):
        return "manifest is not a JSON object"
    problem = _header_problem(manifest)
    if problem:
        return problem
    layers = manifest.get("layers")
    if not isinstance(layers, list):
        return "'layers' must be a list"
    pixels = manifest["image"]["width"] * manifest["image"]["height"]
    for position, entry in enumerate(layers):
        problem = _layer_problem(entry, position, pixels)
        if problem:
            return problem
    return _grading_problem(manifest) or _parts_problem(manifest) or _placement_problem(manifest)


def _parts_problem(manifest: dict) -> str | None:
    """The first problem of the parts' designed volumes (``parts[].volume_mm3``: a number >= 0, or null or
    absent when not known), or None."""
    parts = manifest.get("parts")
    for number, part in enumerate(parts if isinstance(parts, list) else []):
        volume = part.get("volume_mm3") if isinstance(part, dict) else None
        if volume is not None and not (_is_number(volume) and volume >= 0):
            return f"parts[{number}]: 'volume_mm3' must be a number >= 0 or null, not {_show(volume)}"
    return None


def _placement_problem(manifest: dict) -> str | None:
    """The problem of a volume stack's optional ``placement`` (an object whose ``printer_from_scan`` is a
    4 x 4 matrix of numbers and ``print_origin_in_scan_mm`` three numbers), or None."""
    placement = manifest.get("placement")
    if placement is None:
        return None
    matrix = placement.get("printer_from_scan") if isinstance(placement, dict) else None
    origin = placement.get("print_origin_in_scan_mm") if isinstance(placement, dict) else None
    if not (isinstance(matrix, list) and len(matrix) == 4 and all(
            isinstance(row, list) and len(row) == 4 and all(_is_number(v) for v in row) for row in matrix)):
        return "'placement.printer_from_scan' must be a 4 x 4 matrix of numbers"
    if not (isinstance(origin, list) and len(origin) == 3 and all(_is_number(v) for v in origin)):
        return "'placement.print_origin_in_scan_mm' must be three numbers"
    return None


def _grading_problem(manifest: dict) -> str | None:
    """The first problem of ``grading`` (an object, its ``materials`` a list of {name, channel}) and of the
    layers' droplet masks against those materials (each layer's masks, when it has any, are one per material
    in the same order), or None. A stack without ``grading.materials`` may list any masks."""
    grading = manifest.get("grading")
    if grading is None:
        return None
    if not isinstance(grading, dict):
        return "'grading' must be an object"
    halftone = grading.get("halftone", DEFAULT_HALFTONE)
    if not (isinstance(halftone, str) and halftone in HALFTONE_METHODS):
        return f"grading.halftone is {_show(halftone)}, not one of {', '.join(HALFTONE_METHODS)}"
    materials = grading.get("materials")
    if materials is None:
        return None
    if not (isinstance(materials, list) and all(isinstance(m, dict) and isinstance(m.get("name"), str)
                                                for m in materials)):
        return "'grading.materials' must be a list of objects with a 'name'"
    for material in materials:
        if material.get("channel") is not None and not is_channel(material["channel"]):
            return (f"grading.materials: {material['name']!r} has printer channel {_show(material['channel'])}, "
                    f"not a whole number from 1 to {MAX_CHANNEL}")
    names = [material["name"] for material in materials]
    for entry in manifest["layers"]:
        masks = [channel.get("material") for channel in entry.get("channels", [])]
        if masks and masks != names:
            return (f"layer {entry['index']}: its droplet masks ({', '.join(map(str, masks))}) are not one per "
                    f"material of grading.materials ({', '.join(names)}), in its order")
    return None


def _header_problem(manifest: dict) -> str | None:
    """The first problem of the manifest's fields other than ``layers``, or None."""
    if manifest.get("format") != FORMAT_NAME:
        return f"format is {_show(manifest.get('format'))}, expected {FORMAT_NAME!r}"
    if not _is_int(manifest.get("version")) or manifest["version"] != FORMAT_VERSION:
        return f"version {_show(manifest.get('version'))} is not supported (expected {FORMAT_VERSION})"
    if manifest.get("complete") is not True:
        return "stack is not complete (an interrupted slice?): run that slice again with --force to replace it"
    image = manifest.get("image")
    if not isinstance(image, dict):
        return "missing 'image'"
    width, height = image.get("width"), image.get("height")
    if not all(_is_int(v) and v > 0 for v in (width, height)):
        return "image width/height must be positive integers"
    if width * height > MAX_IMAGE_PIXELS:
        return f"image of {width} x {height} pixels exceeds the limit of {MAX_IMAGE_PIXELS}"
    if not isinstance(image.get("mode", "1"), str) or image.get("mode", "1") not in IMAGE_MODES:
        return f"image mode must be one of {', '.join(IMAGE_MODES)}, not {_show(image.get('mode'))}"
    if manifest.get("mask") not in ("alpha", "nonzero"):
        return f"mask must be 'alpha' or 'nonzero', not {_show(manifest.get('mask'))}"
    if manifest["mask"] == "alpha" and image.get("mode", "1") != "RGBA":
        return "mask 'alpha' needs image mode 'RGBA'"
    for key in ("dpi", "pixel_size_mm"):
        pair = manifest.get(key)
        if not (isinstance(pair, list) and len(pair) == 2 and all(_is_number(v) and v > 0 for v in pair)):
            return f"'{key}' must be two positive numbers"
    if not (_is_number(manifest.get("layer_height_mm")) and manifest["layer_height_mm"] > 0):
        return "'layer_height_mm' must be a positive number"
    if "scale" in manifest and not (_is_number(manifest["scale"]) and manifest["scale"] > 0):
        return f"'scale' must be a positive number, not {_show(manifest['scale'])}"
    z_range = manifest.get("z_range_mm")
    if not (isinstance(z_range, list) and len(z_range) == 2 and all(_is_number(v) for v in z_range)
            and z_range[0] <= z_range[1]):
        return "'z_range_mm' must be two numbers [z_min, z_max] (the layer count and heights follow from it)"
    return None


def _layer_problem(entry, position: int, pixels: int) -> str | None:
    """The first problem of layer entry ``position``, or None."""
    if not isinstance(entry, dict):
        return f"layer entry {position} is not an object"
    if not _is_int(entry.get("index")) or entry["index"] != position:
        return f"layer entry {position} has index {_show(entry.get('index'))} (layers must be 0..n-1 in order)"
    if not _is_number(entry.get("z_mm")):
        return f"layer {position}: missing or malformed 'z_mm'"
    if not _is_int(entry.get("solid_pixels")):
        return f"layer {position}: missing or malformed 'solid_pixels'"
    problem = _file_entry_problem(entry, f"layer {position}", pixels)
    if problem:
        return problem
    channels = entry.get("channels", [])
    if not isinstance(channels, list):
        return f"layer {position}: 'channels' must be a list"
    for number, channel in enumerate(channels):
        if not isinstance(channel, dict):
            return f"layer {position}: channel {number} is not an object"
        problem = _file_entry_problem(channel, f"layer {position} channel {number}", pixels)
        if problem:
            return problem
    return None


def widest_masks(manifest: dict) -> list[dict]:
    """The droplet mask entries of the layer that has the most ([] without masks): what the stack's masks are,
    in the order every layer lists them."""
    return max((entry.get("channels", []) for entry in manifest["layers"]), key=len, default=[])


def mask_channels(manifest: dict, label: object = "stack") -> tuple[int, ...]:
    """The printer channel (1-based) of each droplet mask of a checked manifest (:func:`manifest_problem`), in
    the order of a layer's ``channels`` list: the ``channel`` of its ``grading.materials`` entry (the same
    order). A mask whose material names no channel (null, or a stack without ``grading.materials``) takes the
    lowest channel no other mask names, in mask order, so a stack whose materials name none is sent on 1..K
    as listed. The one place a stack's material -> channel map is read (by verify and print). Raises
    VerifyError (naming ``label``) when two masks name one channel."""
    widest = widest_masks(manifest)
    recorded = (manifest.get("grading") or {}).get("materials") or []
    wanted = [recorded[number].get("channel") if number < len(recorded) else None for number in range(len(widest))]
    shared = shared_channel([(str(mask.get("material", f"mask {n + 1}")), channel)
                             for n, (mask, channel) in enumerate(zip(widest, wanted))])
    if shared is not None:
        raise VerifyError(f"{label}: materials {', '.join(shared[1])} all name printer channel {shared[0]}; give "
                          "each material its own channel in the materials file and slice again")
    named = [value for value in wanted if value is not None]
    free = (number for number in range(1, len(wanted) + len(named) + 1) if number not in named)
    return tuple(value if value is not None else next(free) for value in wanted)


def expected_layer_count(z_min: float, z_max: float, layer_height: float) -> int:
    """Layers a stack of this z-range needs: :func:`heoslice.layers.planes.layer_count`, as slicing cuts them
    (imported here: the layers package loads the slicing stage, which a reader of a stack does not need)."""
    from heoslice.layers.planes import layer_count

    return layer_count(z_min, z_max, layer_height)


def layer_height_problems(manifest: dict, z_min: float, z_max: float, source: str) -> list[str]:
    """Layer count and heights against a z-range: z_i = z_min + (i + 1/2) h, count = ceil((z_max - z_min) / h).

    Uses only the required fields (``layer_height_mm``, ``layers[].z_mm``), so a stack cut short
    or reordered is caught whatever optional fields say.
    """
    h = manifest["layer_height_mm"]
    layers = manifest["layers"]
    problems = []
    expected = expected_layer_count(z_min, z_max, h)
    if len(layers) != expected:
        needs = f"more than {MAX_LAYERS}" if expected > MAX_LAYERS else str(expected)
        problems.append(f"{len(layers)} layers, but {source} z-range {z_min:g} .. {z_max:g} mm at "
                        f"{h:g} mm needs {needs}")
    z = np.array([entry["z_mm"] for entry in layers], dtype=np.float64)
    with np.errstate(all="ignore"):
        want = z_min + (np.arange(len(z)) + 0.5) * h
        tolerance = 1e-6 * max(1.0, abs(z_min), abs(z_max)) + 1e-9 * len(z) * h
        off = np.flatnonzero(~(np.abs(z - want) <= tolerance))
    if len(off):
        first = int(off[0])
        problems.append(f"layer {first}: z_mm {z[first]:.6g}, expected {want[first]:.6g} from {source} "
                        f"z_min {z_min:g} + ({first} + 1/2) x {h:g} ({len(off)} layer(s) off)")
    return problems


def source_scale(manifest: dict) -> float:
    """The factor the source file's coordinates were multiplied by before slicing (``slice --scale``): the
    manifest's ``scale``, 1.0 for a stack written before it was recorded."""
    return float(manifest.get("scale", 1.0))


def stack_volume_mm3(manifest: dict) -> float:
    """Solid pixels x pixel area x layer height, summed over layers (mm^3)."""
    px, py = manifest["pixel_size_mm"]
    return float(sum(entry["solid_pixels"] for entry in manifest["layers"]) * px * py * manifest["layer_height_mm"])
