"""Files in and out: regular-file checks and bounded reads of every input, and the one output rule.

Anything that is not a regular file (a FIFO, /dev/zero, a directory, a symlink loop) is
one line naming the file, refused before a byte is read, so no read can block forever or
run without end. Reads are bounded: a file larger than its limit is refused from its
size, and one that grows while being read is refused.

Outputs (a stack, a coloured PLY, an export, a preview PNG, a print log) follow one rule,
:func:`check_output`: a symbolic link is refused, never written through; the input, a folder
holding it or a place inside it is never an output; a device, FIFO or socket is never
replaced; ``--force`` replaces only what heoslice itself wrote (each writer says how it
recognises its own). Files and folders are written under a temporary name beside the final
one (:func:`partial_path`) and renamed into place when complete; a temporary name left by a
killed run is removed by the next run to the same output (:func:`remove_stale_partials`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

from heoslice.errors import InputError, OutputError

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
_OS_PROBLEMS = {errno.ENOENT: "no such file", errno.ELOOP: "symlink loop (too many levels of symbolic links)",
                errno.EACCES: "permission denied", errno.EPERM: "permission denied",
                errno.ENOTDIR: "no such file (a parent is not a directory)",
                errno.ENAMETOOLONG: "file name too long"}


def os_problem(path: str | os.PathLike, err: OSError) -> str:
    """The one-line message for an OSError met while opening ``path`` (broken symlinks said as such)."""
    if err.errno == errno.ENOENT and os.path.islink(path):
        return f"{path}: no such file (broken symbolic link to {os.readlink(path)})"
    return f"{path}: {_OS_PROBLEMS.get(err.errno, err.strerror or type(err).__name__)}"


def _refuse_special(path: str | os.PathLike, status: os.stat_result, what: str) -> None:
    """InputError unless ``status`` is a regular file's."""
    if stat.S_ISREG(status.st_mode):
        return
    kind = next((name for test, name in _KINDS if test(status.st_mode)), "not a regular file")
    raise InputError(f"{path}: is {kind}, not a regular {what} file")


def check_regular(path: str | os.PathLike, what: str = "input") -> os.stat_result:
    """The stat of ``path`` (symlinks followed) after refusing anything that is not a regular file, in one line."""
    try:
        status = os.stat(path)
    except OSError as err:
        raise InputError(os_problem(path, err)) from None
    _refuse_special(path, status, what)
    return status


def open_regular(path: str | os.PathLike, what: str = "input") -> BinaryIO:
    """Open ``path`` for binary reading after checking, on the open descriptor, that it is a regular file.

    Opened non-blocking, so a FIFO without a writer is refused instead of blocking; the
    descriptor is blocking again once it is known to be a regular file.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as err:
        raise InputError(os_problem(path, err)) from None
    try:
        _refuse_special(path, os.fstat(descriptor), what)
        os.set_blocking(descriptor, True)
    except BaseException:
        os.close(descriptor)
        raise
    return os.fdopen(descriptor, "rb")


def read_bounded(path: str | os.PathLike, limit: int, what: str = "input") -> bytes:
    """The bytes of regular file ``path``, at most ``limit`` of them.

    A file whose size exceeds ``limit`` is refused before reading; the file is read into
    one buffer of its size (no copies), and one that grows while being read is refused.
    """
    with open_regular(path, what) as handle:
        size = os.fstat(handle.fileno()).st_size
        if size > limit:
            raise InputError(f"{path}: {what} file of {size} bytes is larger than the {limit}-byte limit")
        data = handle.read(size + 1)
    if len(data) > size:
        raise InputError(f"{path}: {what} file grew while being read")
    return data


def refuse_sparse(path: str | os.PathLike, status: os.stat_result, what: str = "input",
                  *, smallest: int = 16 << 20) -> None:
    """InputError for a file of at least ``smallest`` bytes of which fewer than half are stored on disk.

    A sparse file's holes read as zeros that no program wrote: a header can declare any
    count and the size agrees, while the body is nothing. Programs that write meshes do not
    leave holes.
    """
    stored = getattr(status, "st_blocks", None)
    if stored is None or status.st_size < smallest or 512 * stored * 2 >= status.st_size:
        return
    raise InputError(f"{path}: sparse {what} file: {status.st_size} bytes, of which only {512 * stored} are "
                     "stored (the rest are holes that read as zeros)")



# --- the output rule ---------------------------------------------------------------------------

_WRITE_PROBLEMS = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
                   errno.EFBIG: "file size limit exceeded", errno.EROFS: "read-only file system",
                   errno.EACCES: "permission denied", errno.EPERM: "permission denied",
                   errno.ENOENT: "no such directory", errno.ENOTDIR: "a parent is not a directory",
                   errno.ELOOP: "a symbolic link is in the way"}
_PARTIAL = ".partial"


def write_problem(path: str | os.PathLike, err: OSError) -> OutputError:
    """One-line OutputError (exit 3) for a failed write: disk full, quota, file size limit, read-only, permission."""
    return OutputError(f"{path}: cannot write ({_WRITE_PROBLEMS.get(err.errno, err.strerror or str(err))})")


def _relation(target: str, source: str) -> str | None:
    """How output path ``target`` meets input path ``source`` (both real paths): None when apart."""
    if target == source:
        return "is the input"
    if source.startswith(target.rstrip(os.sep) + os.sep):
        return "holds the input"
    if target.startswith(source.rstrip(os.sep) + os.sep):
        return "is inside the input"
    return None


def _a(what: str) -> str:
    """``what`` with its indefinite article."""
    return f"{'an' if what[0] in 'aeiou' else 'a'} {what}"


def check_output(target: str | os.PathLike, what: str, *, force: bool, made_here: Callable[[Path], bool],
                 inputs: Iterable[str | os.PathLike] = (), folder: bool = False,
                 empty_folder_is_free: bool = False) -> bool:
    """Apply the output rule to ``target`` before anything is written; True when it exists (and may be replaced).

    ``what`` names the output in messages ("export", "preview PNG"); ``made_here(path)`` says whether an
    existing ``target`` is such an output written by heoslice (the only thing ``force`` replaces);
    ``inputs`` are the command's input files or folders; ``folder`` says the output is a directory.
    Every refusal is one OutputError line (exit 3).
    """
    target = Path(target)
    if os.path.islink(target):
        raise OutputError(f"{target}: is a symbolic link; heoslice does not write through links "
                          f"(give the path it points to, or another name)")
    real = os.path.realpath(target)
    for source in inputs:
        relation = _relation(real, os.path.realpath(source))
        if relation:
            raise OutputError(f"{target}: {relation} {source}; heoslice never writes over its input "
                              f"(choose another {what} name)")
    try:
        status = os.lstat(target)
    except FileNotFoundError:
        return False
    except OSError as err:
        raise write_problem(target, err) from None
    is_dir, is_file = stat.S_ISDIR(status.st_mode), stat.S_ISREG(status.st_mode)
    if not (is_dir or is_file):
        kind = next((name for test, name in _KINDS if test(status.st_mode)), "not a regular file")
        raise OutputError(f"{target}: is {kind}, not {_a(what)} heoslice wrote; heoslice never replaces it")
    if is_dir != folder:
        raise OutputError(f"{target}: is {'a directory' if is_dir else 'a file'}, not {_a(what)}")
    if empty_folder_is_free and is_dir and not any(os.scandir(target)):
        return False
    if not force:
        raise OutputError(f"{target}: exists{' and is not empty' if is_dir else ''} (use --force to replace it)")
    if not made_here(target):
        raise OutputError(f"{target}: exists and is not {_a(what)} heoslice wrote; --force replaces only "
                          f"heoslice's own outputs (remove it yourself, or choose another name)")
    return True


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _partial_pattern(target: Path) -> re.Pattern:
    return re.compile(rf"^\.{re.escape(target.name)}\.(\d+)\.[^.]+{re.escape(_PARTIAL)}$")


def remove_stale_partials(target: str | os.PathLike) -> list[Path]:
    """Remove the temporary names beside ``target`` left by runs that died (their process is gone); return them.

    Only names of :func:`partial_path`'s form for this very target are touched, never anything else.
    """
    target = Path(target)
    parent = target.parent
    pattern, removed = _partial_pattern(target), []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for entry in entries:
        found = pattern.match(entry.name)
        if not found or _pid_alive(int(found.group(1))):
            continue
        path = parent / entry.name
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(path)
            else:
                path.unlink()
        except OSError:
            continue
        removed.append(path)
    return removed


def partial_path(target: str | os.PathLike, folder: bool = False) -> Path:
    """A new empty temporary file or folder beside ``target``, named ``.<name>.<pid>.<random>.partial``.

    Hidden, marked temporary, and carrying the writer's process id so that the next run removes it
    when the writer died (:func:`remove_stale_partials`). OSError becomes one OutputError line.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    remove_stale_partials(target)
    prefix = f".{target.name}.{os.getpid()}."
    try:
        if folder:
            return Path(tempfile.mkdtemp(prefix=prefix, suffix=_PARTIAL, dir=parent))
        handle, name = tempfile.mkstemp(prefix=prefix, suffix=_PARTIAL, dir=parent)
        os.close(handle)
        return Path(name)
    except OSError as err:
        raise write_problem(target, err) from None


def umask() -> int:
    """The process's file-creation mask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def move_into_place(partial: Path, target: str | os.PathLike, folder: bool = False) -> None:
    """Rename the finished ``partial`` to ``target`` (already checked by :func:`check_output`), with the
    mode a new file or folder gets; an old folder output is moved aside first and removed after."""
    target = Path(target)
    aside = None
    try:
        os.chmod(partial, (0o777 if folder else 0o666) & ~umask())
        if folder and os.path.isdir(target) and not os.path.islink(target):
            aside = partial_path(target, folder=True)
            os.replace(target, aside)
        os.replace(partial, target)
    except BaseException as err:  # a failure, or a signal between the two renames: the old output put back
        if aside is not None and not os.path.lexists(target):
            with contextlib.suppress(OSError):
                os.replace(aside, target)
        discard_partial(partial)
        if isinstance(err, OSError):
            raise write_problem(target, err) from None
        raise
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)


def discard_partial(partial: Path | None) -> None:
    """Remove a temporary file or folder of :func:`partial_path` (after a failure or an interruption)."""
    if partial is None or not os.path.lexists(partial):
        return
    if os.path.isdir(partial) and not os.path.islink(partial):
        shutil.rmtree(partial, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            os.unlink(partial)


def write_output(target: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to the file ``target`` atomically: a partial file beside it, fsync, rename into place.

    Call :func:`check_output` first. Disk errors become one OutputError line; nothing is left behind.
    """
    target = Path(target)
    partial = partial_path(target)
    try:
        with open(partial, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
    except OSError as err:
        discard_partial(partial)
        raise write_problem(target, err) from None
    except BaseException:
        discard_partial(partial)
        raise
    move_into_place(partial, target)
    return target


def head_bytes(path: str | os.PathLike, count: int = 4096) -> bytes:
    """The first ``count`` bytes of the regular file ``path`` (empty for anything unreadable), for recognising
    an output heoslice wrote."""
    try:
        with open_regular(path, "output") as handle:
            return handle.read(count)
    except (InputError, OSError):
        return b""
