"""The stack on disk: layer TIFFs plus ``manifest.json``, written safely and verified.

The format is documented in ``docs/stack-format.md``. The manifest is written last,
atomically (temporary file, fsync, rename), so a directory is a complete stack
only when its manifest says so; an interrupted run leaves no manifest behind.
Reading is defensive: paths must stay inside the stack, image sizes are checked
against the manifest before any pixel is decoded.
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice import __version__
from heoslice.errors import InputError, OutputError, VerifyError

FORMAT_NAME = "heoslice-stack"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
LAYER_PATTERN = re.compile(r"^layer_\d{5,}(_[A-Za-z0-9-]+)?\.tif$")
#: Compression name -> tifffile argument. Default chosen by measurement (see README).
COMPRESSIONS = {"deflate": "zlib", "packbits": "packbits", "lzw": "lzw", "none": None}
DEFAULT_COMPRESSION = "deflate"
#: Largest manifest accepted, bytes; larger is refused before parsing.
MAX_MANIFEST_BYTES = 64 << 20
#: Largest image accepted by readers, pixels (a 1 m x 1 m plate at 600 dpi is 5.6e8).
MAX_IMAGE_PIXELS = 1 << 30


def layer_file_name(index: int, channel: str | None = None) -> str:
    """File name of layer ``index`` (and of one of its channels), e.g. 'layer_00042.tif'."""
    suffix = f"_{channel}" if channel else ""
    return f"layer_{index:05d}{suffix}.tif"


def prepare_directory(directory: Path, force: bool) -> None:
    """Create the output directory, refusing a non-empty one unless ``force``.

    With ``force``, the old manifest is removed first (so the directory never looks
    complete while being rewritten), then the old layer files.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise OutputError(f"{directory}: exists and is not a directory")
    try:
        directory.mkdir(parents=True, exist_ok=True)
        existing = list(directory.iterdir())
    except OSError as err:
        raise OutputError(f"{directory}: cannot create output directory ({err.strerror})") from err
    if existing and not force:
        raise OutputError(f"{directory}: directory is not empty (use --force to overwrite)")
    try:
        for stale in (directory / MANIFEST, directory / (MANIFEST + ".tmp")):
            if stale.exists():
                stale.unlink()
        _fsync_directory(directory)
        for entry in existing:
            if entry.is_file() and LAYER_PATTERN.match(entry.name):
                entry.unlink()
    except OSError as err:
        raise OutputError(f"{directory}: cannot clear old stack ({err.strerror})") from err
    if not os.access(directory, os.W_OK):
        raise OutputError(f"{directory}: directory is not writable")


def encode_tiff(image: np.ndarray, dpi: tuple[float, float], compression: str) -> bytes:
    """TIFF bytes of one layer image: bool (h, w) as 1-bit, uint8 (h, w) grey, or (h, w, 4) RGBA.

    Resolution tags carry the dpi with ResolutionUnit inch, so viewers show true size.
    """
    import tifffile

    options: dict = {
        "resolution": (float(dpi[0]), float(dpi[1])),
        "resolutionunit": "INCH",
        "rowsperstrip": 64,
        "compression": COMPRESSIONS[compression],
        "software": f"heoslice {__version__}",
    }
    if compression == "deflate":
        options["compressionargs"] = {"level": 1}
    if image.ndim == 3:
        options.update(photometric="rgb", extrasamples=["unassalpha"])
    else:
        options["photometric"] = "minisblack"
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, image, **options)
    return buffer.getvalue()


def write_file(path: Path, data: bytes) -> str:
    """Write bytes to ``path``; return their SHA-256. Disk errors become one-line OutputErrors."""
    try:
        with open(path, "wb") as handle:
            handle.write(data)
    except OSError as err:
        if err.errno == errno.ENOSPC:
            raise OutputError(f"{path}: no space left on device") from err
        raise OutputError(f"{path}: cannot write ({err.strerror})") from err
    return hashlib.sha256(data).hexdigest()


def _fsync_directory(directory: Path) -> None:
    try:
        handle = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(handle)
    except OSError:
        pass
    finally:
        os.close(handle)


def write_manifest(directory: Path, manifest: dict) -> Path:
    """Write ``manifest.json`` atomically: temporary file, fsync, rename, fsync of the directory."""
    directory = Path(directory)
    target = directory / MANIFEST
    temporary = directory / (MANIFEST + ".tmp")
    text = json.dumps(manifest, indent=1) + "\n"
    try:
        with open(temporary, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, target)
    except OSError as err:
        if err.errno == errno.ENOSPC:
            raise OutputError(f"{target}: no space left on device") from err
        raise OutputError(f"{target}: cannot write ({err.strerror})") from err
    _fsync_directory(directory)
    return target


@dataclass(frozen=True)
class StackReport:
    """Outcome of :func:`verify_stack`: ``problems`` (one line each; empty when clean) and the manifest."""

    directory: Path
    problems: tuple[str, ...]
    manifest: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.problems


def read_manifest(directory: Path) -> dict:
    """Parse and structurally check ``manifest.json``; raise VerifyError naming the first problem."""
    directory = Path(directory)
    path = directory / MANIFEST
    if not directory.is_dir():
        raise VerifyError(f"{directory}: not a directory")
    if not path.is_file():
        raise VerifyError(f"{directory}: no {MANIFEST} (not a stack, or an interrupted run)")
    if path.stat().st_size > MAX_MANIFEST_BYTES:
        raise VerifyError(f"{path}: manifest is larger than {MAX_MANIFEST_BYTES} bytes")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise VerifyError(f"{path}: not valid JSON ({err})") from err
    except RecursionError as err:
        raise VerifyError(f"{path}: JSON nested too deeply") from err
    problem = _manifest_shape_problem(manifest)
    if problem:
        raise VerifyError(f"{path}: {problem}")
    return manifest


def _manifest_shape_problem(manifest) -> str | None:
    """The first structural problem of a parsed manifest, or None."""
    if not isinstance(manifest, dict):
        return "manifest is not a JSON object"
    if manifest.get("format") != FORMAT_NAME:
        return f"format is {manifest.get('format')!r}, expected {FORMAT_NAME!r}"
    if manifest.get("version") != FORMAT_VERSION:
        return f"version {manifest.get('version')!r} is not supported (expected {FORMAT_VERSION})"
    if manifest.get("complete") is not True:
        return "stack is not complete (interrupted run?)"
    image = manifest.get("image")
    if not isinstance(image, dict):
        return "missing 'image'"
    width, height = image.get("width"), image.get("height")
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (width, height)):
        return "image width/height must be positive integers"
    if width * height > MAX_IMAGE_PIXELS:
        return f"image of {width} x {height} pixels exceeds the limit of {MAX_IMAGE_PIXELS}"
    if manifest.get("mask") not in ("alpha", "nonzero"):
        return f"mask must be 'alpha' or 'nonzero', not {manifest.get('mask')!r}"
    for key in ("dpi", "pixel_size_mm"):
        pair = manifest.get(key)
        if not (isinstance(pair, list) and len(pair) == 2
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in pair)):
            return f"'{key}' must be two positive numbers"
    height_mm = manifest.get("layer_height_mm")
    if not isinstance(height_mm, (int, float)) or isinstance(height_mm, bool) or not height_mm > 0:
        return "'layer_height_mm' must be a positive number"
    layers = manifest.get("layers")
    if not isinstance(layers, list):
        return "'layers' must be a list"
    for position, entry in enumerate(layers):
        if not isinstance(entry, dict):
            return f"layer entry {position} is not an object"
        if entry.get("index") != position:
            return f"layer entry {position} has index {entry.get('index')!r} (layers must be 0..n-1 in order)"
        for key, kind in (("file", str), ("sha256", str), ("solid_pixels", int), ("z_mm", (int, float))):
            if not isinstance(entry.get(key), kind) or isinstance(entry.get(key), bool):
                return f"layer {position}: missing or malformed '{key}'"
    return None


def resolve_inside(directory: Path, name: str) -> Path | None:
    """``directory / name`` if it stays inside ``directory`` (no absolute paths, '..', or links out)."""
    if not name or os.path.isabs(name) or "\\" in name or "\x00" in name:
        return None
    root = Path(directory).resolve()
    candidate = (root / name).resolve()
    if candidate.parent != root and root not in candidate.parents:
        return None
    return candidate


def _tiff_header_problem(path: Path, width: int, height: int, dpi: list) -> str | None:
    """Check size and resolution tags of a layer TIFF without decoding pixels."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tiff:
            if len(tiff.pages) != 1:
                return f"{path.name}: has {len(tiff.pages)} pages, expected 1"
            page = tiff.pages[0]
            if (page.imagewidth, page.imagelength) != (width, height):
                return (f"{path.name}: is {page.imagewidth} x {page.imagelength} pixels, "
                        f"manifest says {width} x {height}")
            tags = page.tags
            if "XResolution" in tags and "YResolution" in tags:
                xres = tags["XResolution"].value
                yres = tags["YResolution"].value
                found = (xres[0] / xres[1], yres[0] / yres[1])
                if not np.allclose(found, dpi, rtol=1e-6):
                    return f"{path.name}: resolution {found[0]:g} x {found[1]:g} dpi, manifest says {dpi[0]:g} x {dpi[1]:g}"
            else:
                return f"{path.name}: has no resolution tags"
    except Exception as err:  # tifffile raises many types on corrupt files
        return f"{path.name}: not a readable TIFF ({' '.join(str(err).split())[:120]})"
    return None


def decode_mask(path: Path, manifest: dict) -> np.ndarray:
    """The solid mask ((height, width) bool) of one layer image file, after checking its size."""
    import tifffile

    width, height = manifest["image"]["width"], manifest["image"]["height"]
    problem = _tiff_header_problem(path, width, height, manifest["dpi"])
    if problem:
        raise VerifyError(problem)
    try:
        pixels = tifffile.imread(path)
    except Exception as err:
        raise VerifyError(f"{path.name}: cannot decode ({' '.join(str(err).split())[:120]})") from err
    if manifest["mask"] == "alpha":
        if pixels.ndim != 3 or pixels.shape[2] != 4:
            raise VerifyError(f"{path.name}: mask 'alpha' needs an RGBA image, found shape {pixels.shape}")
        return pixels[:, :, 3] > 0
    return pixels != 0 if pixels.ndim == 2 else np.any(pixels != 0, axis=2)


def read_layer_mask(directory: Path, manifest: dict, index: int) -> np.ndarray:
    """Solid mask of layer ``index`` of a (verified) stack: (height, width) bool."""
    entry = manifest["layers"][index]
    path = resolve_inside(Path(directory), entry["file"])
    if path is None:
        raise VerifyError(f"layer {index}: file {entry['file']!r} lies outside the stack")
    return decode_mask(path, manifest)


def verify_stack(directory: Path, *, check_pixels: bool = True) -> StackReport:
    """Check a stack: manifest, every listed file (inside, present, sha256, size, dpi, solid pixels), extras.

    Returns a report listing every problem found, one line each.
    """
    directory = Path(directory)
    try:
        manifest = read_manifest(directory)
    except VerifyError as err:
        return StackReport(directory, (str(err),))
    problems: list[str] = []
    listed: set[str] = set()
    for entry in manifest["layers"]:
        index = entry["index"]
        files = [(entry["file"], entry["sha256"], entry.get("solid_pixels"))]
        for channel in entry.get("channels", []) or []:
            if isinstance(channel, dict) and isinstance(channel.get("file"), str):
                files.append((channel["file"], channel.get("sha256"), None))
            else:
                problems.append(f"layer {index}: malformed channel entry")
        for name, digest, solid in files:
            path = resolve_inside(directory, name)
            if path is None:
                problems.append(f"layer {index}: file {name!r} lies outside the stack")
                continue
            listed.add(path.name)
            if not path.is_file():
                problems.append(f"layer {index}: {name} is missing")
                continue
            with open(path, "rb") as handle:
                actual = hashlib.file_digest(handle, "sha256").hexdigest() if hasattr(hashlib, "file_digest") \
                    else hashlib.sha256(handle.read()).hexdigest()
            if actual != digest:
                problems.append(f"layer {index}: {name} sha256 does not match the manifest (file altered)")
                continue
            problem = _tiff_header_problem(path, manifest["image"]["width"], manifest["image"]["height"],
                                           manifest["dpi"])
            if problem:
                problems.append(f"layer {index}: {problem}")
                continue
            if check_pixels and solid is not None:
                try:
                    found = int(np.count_nonzero(decode_mask(path, manifest)))
                except VerifyError as err:
                    problems.append(f"layer {index}: {err}")
                    continue
                if found != solid:
                    problems.append(f"layer {index}: {name} has {found} solid pixels, manifest says {solid}")
    for entry in sorted(directory.iterdir()):
        if LAYER_PATTERN.match(entry.name) and entry.name not in listed:
            problems.append(f"{entry.name}: layer file not listed in the manifest")
    return StackReport(directory, tuple(problems), manifest)


def load_verified(directory: Path) -> dict:
    """The manifest of a stack that passes :func:`verify_stack`; raise VerifyError with its problems otherwise."""
    report = verify_stack(directory)
    if not report.ok:
        more = f" (and {len(report.problems) - 1} more problem(s))" if len(report.problems) > 1 else ""
        raise VerifyError(f"{directory}: {report.problems[0]}{more}")
    return report.manifest


def stack_volume_mm3(manifest: dict) -> float:
    """Solid pixels x pixel area x layer height, summed over layers (mm^3)."""
    px, py = manifest["pixel_size_mm"]
    return float(sum(entry["solid_pixels"] for entry in manifest["layers"]) * px * py * manifest["layer_height_mm"])


def check_input_path(path: Path) -> Path:
    """A stack directory argument: must exist and be a directory."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such directory")
    if not path.is_dir():
        raise InputError(f"{path}: not a directory")
    return path
