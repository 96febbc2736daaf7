"""Reading a stack defensively: paths stay inside it, the manifest is bounded before it is parsed,
a layer file's bytes are bounded by its checked layout and hashed before they are decoded."""

from __future__ import annotations

import hashlib
import io
import os
import re
import stat
from pathlib import Path

import numpy as np

from heoslice.errors import InputError, VerifyError
from heoslice.stack.manifest import LAYER_PATTERN, MANIFEST, MASK_MODE, MAX_MANIFEST_BYTES, parse_manifest
from heoslice.stack.tiff import checked_page, decode_solid, file_limit, open_tiff

#: Largest decoded strip a streaming reader accepts, bytes (heoslice writes strips of 64 or 256 rows:
#: a 1 m wide layer at 600 dpi decodes to 6 MB per strip).
MAX_STRIP_BYTES = 1 << 26
#: A file name with no separator, no leading dot and nothing a path could read otherwise (layer files are).
_PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*\Z")

def read_manifest(directory: Path) -> dict:
    """Parse and structurally check ``manifest.json``; raise VerifyError naming the first problem.

    The manifest must be a regular file inside the stack (a symlink out is refused),
    at most MAX_MANIFEST_BYTES long; :func:`~heoslice.stack.manifest.parse_manifest` bounds its
    objects and arrays, so parsing it cannot read outside the stack or allocate without bound.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise VerifyError(f"{directory}: not a directory")
    path = directory / MANIFEST
    if not (path.exists() or path.is_symlink()):
        if _holds_layer_files(directory):
            raise VerifyError(incomplete_stack(directory))
        raise VerifyError(f"{directory}: no {MANIFEST} (not a stack)")
    inside = resolve_inside(directory, MANIFEST)
    if inside is None:
        raise VerifyError(f"{path}: is a link to outside the stack")
    if not inside.is_file():
        raise VerifyError(f"{path}: is not a regular file")
    try:
        with open_regular(inside, str(path)) as handle:  # read(n) allocates n bytes: ask for the size only
            size = os.fstat(handle.fileno()).st_size
            if size > MAX_MANIFEST_BYTES:
                raise VerifyError(f"{path}: manifest is larger than {MAX_MANIFEST_BYTES} bytes")
            raw = handle.read(size + 1)
    except OSError as err:
        raise VerifyError(f"{path}: cannot read ({err.strerror})") from err
    return parse_manifest(raw, path)


def incomplete_stack(directory: Path) -> str:
    """What a directory a slice left without its manifest is, and what to run: the one wording of ``verify``
    and of an interrupted ``slice``."""
    return (f"{directory}: incomplete stack, no {MANIFEST} (the slice that wrote it was interrupted or failed); "
            "run that slice again with --force to replace it")


def _holds_layer_files(directory: Path) -> bool:
    """Whether ``directory`` holds a file named like a layer or droplet mask."""
    try:
        return any(LAYER_PATTERN.match(entry.name) for entry in os.scandir(directory))
    except OSError:
        return False


def resolve_inside(directory: Path, name: str, resolved: bool = False) -> Path | None:
    """``directory / name`` if it stays inside ``directory`` (no absolute paths, '..', or links out);
    ``resolved``: ``directory`` is already its resolved path (a caller checking many names resolves it once)."""
    if not isinstance(name, str) or not name or os.path.isabs(name) or "\\" in name or "\x00" in name:
        return None
    root = Path(directory) if resolved else Path(directory).resolve()
    if _PLAIN_NAME.match(name):  # a file of the folder itself: inside unless it is a link (resolved below)
        candidate = root / name
        try:
            if not stat.S_ISLNK(os.lstat(candidate).st_mode):
                return candidate
        except OSError:  # absent: resolving it would give the same path
            return candidate
    try:
        candidate = (root / name).resolve()
    except (OSError, RuntimeError):  # symlink loops
        return None
    if candidate.parent != root and root not in candidate.parents:
        return None
    return candidate


def regular_files(directory: Path) -> set[str]:
    """Names of the regular files (not links) directly in ``directory`` that :func:`resolve_inside` takes as
    plain names, from one listing: each is inside it and a file, as resolve_inside and a stat would find,
    without a system call per name."""
    try:
        with os.scandir(directory) as entries:
            return {entry.name for entry in entries
                    if _PLAIN_NAME.match(entry.name) and entry.is_file(follow_symlinks=False)}
    except OSError:
        return set()


def open_regular(path: Path | str, name: str):
    """``path`` opened for binary reading if it is a regular file; VerifyError otherwise. Opened without
    blocking, so a FIFO or device planted in a stack is refused instead of waited on forever."""
    handle = open(path, "rb", opener=lambda target, flags: os.open(target, flags | os.O_NONBLOCK))
    if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
        handle.close()
        raise VerifyError(f"{name}: is not a regular file")
    os.set_blocking(handle.fileno(), True)
    return handle


def read_small_regular(path: Path | str, name: str, most: int) -> bytes | None:
    """The bytes of ``path`` if it is a regular file of at most ``most`` bytes (read to its end, a byte more
    than its size asked for, so that a file grown since is seen), None if it is larger; VerifyError if it is
    not a regular file. :func:`open_regular`'s rules in system calls alone: a stack's thousands of small
    files are read without a file object each."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        status = os.fstat(fd)
        if not stat.S_ISREG(status.st_mode):
            raise VerifyError(f"{name}: is not a regular file")
        if status.st_size > most:
            return None
        wanted = status.st_size + 1
        data = os.read(fd, wanted)
        while len(data) < wanted:
            more = os.read(fd, wanted - len(data))
            if not more:
                break
            data += more
        return data
    finally:
        os.close(fd)


def read_checked(path: Path | str, name: str, sha256: str | None, manifest: dict, mode: str | None) -> bytes:
    """The bytes of a layer file whose TIFF layout passed :func:`checked_page`, at most what that layout
    can need, and matching ``sha256`` when given. Memory: bounded by twice the raw image size."""
    try:
        with open_regular(path, name) as handle:
            size = os.fstat(handle.fileno()).st_size
            with open_tiff(handle, name) as tiff:
                limit = file_limit(checked_page(tiff, name, size, manifest, mode))
            if size > limit:
                raise VerifyError(f"{name}: file is {size} bytes, more than its image can need ({limit})")
            handle.seek(0)
            data = handle.read(size + 1)
    except OSError as err:
        raise VerifyError(f"{name}: cannot read ({err.strerror})") from err
    if len(data) > limit:
        raise VerifyError(f"{name}: file grew while being read")
    if sha256 is not None and hashlib.sha256(data).hexdigest() != sha256:
        raise VerifyError(f"{name}: sha256 does not match the manifest (file altered)")
    return data


def decode_checked(data: bytes, name: str, manifest: dict, mode: str | None, out: np.ndarray | None) -> int:
    """Check the layout of TIFF bytes again and decode them strip by strip; return the solid pixel count."""
    with open_tiff(io.BytesIO(data), name) as tiff:
        page = checked_page(tiff, name, len(data), manifest, mode)
        return decode_solid(page, name, manifest["mask"] == "alpha" and mode is not None, out=out)


def decode_mask(path: Path, manifest: dict, sha256: str | None = None, mode: str | None = None) -> np.ndarray:
    """The solid mask ((height, width) bool) of one layer image file, after checking its layout and bytes.

    The file is read once into memory (bounded by its layout), its SHA-256 checked when
    given, and decoded strip by strip into the mask: what is returned is exactly what
    was hashed. ``mode`` (a manifest image mode) is checked when given; without it the
    image is read as a channel (any non-zero sample is solid).
    """
    if path is None:
        raise VerifyError("layer file lies outside the stack")
    path = Path(path)
    data = read_checked(path, path.name, sha256, manifest, mode)
    image = manifest["image"]
    mask = np.zeros((image["height"], image["width"]), dtype=bool)
    decode_checked(data, path.name, manifest, mode, mask)
    return mask


def read_layer_mask(directory: Path, manifest: dict, index: int) -> np.ndarray:
    """Solid mask of layer ``index`` of a (verified) stack: (height, width) bool; its sha256 is checked again."""
    entry = manifest["layers"][index]
    path = resolve_inside(Path(directory), entry["file"])
    if path is None:
        raise VerifyError(f"layer {index}: file {entry['file']!r} lies outside the stack")
    return decode_mask(path, manifest, sha256=entry["sha256"], mode=manifest["image"].get("mode", "1"))


def read_layer_pixels(directory: Path, manifest: dict, index: int) -> np.ndarray:
    """Pixels of layer ``index`` as stored: (h, w) bool for mode '1', (h, w, 4) uint8 for 'RGBA'.

    The file must stay inside the stack, match its sha256 and pass the layout checks
    of :func:`decode_mask` before a pixel is decoded (for previews).
    """
    entry = manifest["layers"][index]
    path = resolve_inside(Path(directory), entry["file"])
    if path is None:
        raise VerifyError(f"layer {index}: file {entry['file']!r} lies outside the stack")
    mode = manifest["image"].get("mode", "1")
    data = read_checked(path, path.name, entry["sha256"], manifest, mode)
    decode_checked(data, path.name, manifest, mode, None)
    with open_tiff(io.BytesIO(data), path.name) as tiff:
        try:
            return tiff.pages.first.asarray(maxworkers=1)
        except Exception as err:  # corrupt strips raise many types
            raise VerifyError(f"{path.name}: cannot decode ({' '.join(str(err).split())[:120]})") from err


def read_layer_channels(directory: Path, manifest: dict, index: int) -> np.ndarray:
    """Droplet masks of layer ``index``: (channels, height, width) bool, in the order of its ``channels`` list.

    Each file must stay inside the stack, match its sha256 and pass the layout checks
    of :func:`decode_mask` before it is decoded (for previews).
    """
    channels = manifest["layers"][index].get("channels", [])
    image = manifest["image"]
    masks = np.zeros((len(channels), image["height"], image["width"]), dtype=bool)
    for number, channel in enumerate(channels):
        path = resolve_inside(Path(directory), channel["file"])
        if path is None:
            raise VerifyError(f"layer {index}: file {channel['file']!r} lies outside the stack")
        masks[number] = decode_mask(path, manifest, sha256=channel["sha256"], mode=MASK_MODE)
    return masks



def _file_strips(path: Path | None, name: str, sha256: str, manifest: dict, mode: str | None):
    """Yield (first row, (rows, width, samples) pixels) for each strip of one checked layer file, in order.

    Memory: the file's bytes (bounded by its layout) and one decoded strip, at most
    MAX_STRIP_BYTES (refused before decoding otherwise).
    """
    if path is None:
        raise VerifyError(f"{name}: lies outside the stack")
    data = read_checked(path, name, sha256, manifest, mode)
    with open_tiff(io.BytesIO(data), name) as tiff:
        page = checked_page(tiff, name, len(data), manifest, mode)
        rows = min(int(page.rowsperstrip or page.imagelength), page.imagelength)
        decoded = rows * page.imagewidth * page.samplesperpixel
        if decoded > MAX_STRIP_BYTES:
            raise VerifyError(f"{name}: strips of {rows} rows decode to {decoded} bytes, more than the "
                              f"{MAX_STRIP_BYTES} a reader decodes at once")
        try:
            for segment, index, shape in page.segments(maxworkers=1):
                if segment is None:
                    raise VerifyError(f"{name}: a strip is missing")
                yield index[2], segment.reshape(shape[1], shape[2], shape[3])
        except VerifyError:
            raise
        except Exception as err:  # imagecodecs and tifffile raise many types on corrupt strips
            raise VerifyError(f"{name}: cannot decode ({' '.join(str(err).split())[:120]})") from err


def layer_strips(directory: Path, manifest: dict, index: int, channels: bool = False):
    """Yield (first row, layer pixels, droplet-mask pixels) strip by strip for layer ``index`` of a stack.

    Layer pixels are (rows, width, samples) as stored; droplet-mask pixels a list of
    (rows, width, 1) arrays in the order of the layer's masks (empty unless ``channels``). Every file must
    stay inside the stack, match its sha256 and pass the layout checks; the masks must
    be cut into the same strips as their layer. Memory: one strip of each file.
    """
    directory = Path(directory)
    entry = manifest["layers"][index]
    mode = manifest["image"].get("mode", "1")
    readers = [_file_strips(resolve_inside(directory, entry["file"]), f"layer {index}: {entry['file']}",
                            entry["sha256"], manifest, mode)]
    for channel in entry.get("channels", []) if channels else []:
        readers.append(_file_strips(resolve_inside(directory, channel["file"]), f"layer {index}: {channel['file']}",
                                    channel["sha256"], manifest, MASK_MODE))
    for strips in zip(*readers):
        row, pixels = strips[0]
        if any(other_row != row or other.shape[:2] != pixels.shape[:2] for other_row, other in strips[1:]):
            raise VerifyError(f"layer {index}: its droplet masks are cut into other strips than the layer image")
        yield row, pixels, [other for _, other in strips[1:]]


def check_input_path(path: Path) -> Path:
    """A stack directory argument: must exist and be a directory."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such directory")
    if not path.is_dir():
        raise InputError(f"{path}: not a directory")
    return path

