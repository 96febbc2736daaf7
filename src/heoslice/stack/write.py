"""Writing a stack: the output directory, layer files and the manifest, each safely.

Layer files are created without following links planted in the stack; the manifest
is written last and atomically (temporary file, fsync, rename), so a directory is a
complete stack only when its manifest says so.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from pathlib import Path

from heoslice.errors import OutputError
from heoslice.files import check_output, write_problem
from heoslice.stack.manifest import LAYER_PATTERN, MANIFEST, MAX_MANIFEST_BYTES


def is_stack_folder(directory: Path) -> bool:
    """Whether ``directory`` holds nothing but what a slice writes (a manifest, its temporary, layer files):
    a stack, or one a killed slice left incomplete. Only such a folder is replaced by ``slice --force``."""
    try:
        names = [entry.name for entry in os.scandir(directory)]
    except OSError:
        return False
    return all(name in (MANIFEST, MANIFEST + ".tmp") or LAYER_PATTERN.match(name) for name in names)


def check_stack_output(directory: Path, force: bool, inputs: tuple[Path, ...] = ()) -> None:
    """The output rule (:func:`heoslice.files.check_output`) for a stack folder: an empty or missing folder is
    free; an existing stack only with ``force``; never a link, a file, the input's folder or a folder holding
    anything a slice did not write."""
    check_output(directory, "stack folder", force=force, made_here=is_stack_folder, inputs=inputs, folder=True,
                 empty_folder_is_free=True)


def prepare_directory(directory: Path, force: bool, inputs: tuple[Path, ...] = ()) -> None:
    """Create the output directory under the stack's output rule (:func:`check_stack_output`).

    With ``force``, the old manifest is removed first (so the directory never looks
    complete while being rewritten), then the old layer files.
    """
    directory = Path(directory)
    check_stack_output(directory, force, inputs)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        existing = list(directory.iterdir())
    except OSError as err:
        raise OutputError(f"{directory}: cannot create output directory ({err.strerror})") from err
    if existing and not force:
        raise OutputError(f"{directory}: directory is not empty (use --force to overwrite)")
    try:
        for stale in (directory / MANIFEST, directory / (MANIFEST + ".tmp")):
            if os.path.lexists(stale):
                stale.unlink()
        _fsync_directory(directory)
        for entry in existing:
            if LAYER_PATTERN.match(entry.name) and (entry.is_symlink() or entry.is_file()):
                entry.unlink()
    except OSError as err:
        raise OutputError(f"{directory}: cannot clear old stack ({err.strerror})") from err
    if not os.access(directory, os.W_OK):
        raise OutputError(f"{directory}: directory is not writable")


def write_file(path: Path, data: bytes) -> str:
    """Write bytes to ``path``; return their SHA-256. Disk errors become one-line OutputErrors."""
    try:
        with _create(path) as handle:
            handle.write(data)
    except OSError as err:
        raise write_problem(path, err) from err
    return hashlib.sha256(data).hexdigest()


def _create(path: Path):
    """Open ``path`` for writing, truncated, never following a symlink planted in the stack."""
    return os.fdopen(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o666), "wb")


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
    """Write ``manifest.json`` atomically: temporary file, fsync, rename, fsync of the directory.

    A manifest longer than MAX_MANIFEST_BYTES (which readers refuse) is not written; when
    writing fails (disk full, quota), the temporary file is removed: nothing is left behind
    that looks like a manifest.
    """
    directory = Path(directory)
    target = directory / MANIFEST
    temporary = directory / (MANIFEST + ".tmp")
    data = (json.dumps(manifest, indent=1, allow_nan=False) + "\n").encode("utf-8")
    if len(data) > MAX_MANIFEST_BYTES:
        raise OutputError(f"{target}: the manifest would be {len(data)} bytes, more than the "
                          f"{MAX_MANIFEST_BYTES} readers accept (fewer layers or droplet masks)")
    try:
        with _create(temporary) as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, target)
    except OSError as err:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise write_problem(target, err) from err
    _fsync_directory(directory)
    return target
