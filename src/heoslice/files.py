"""Regular-file checks and bounded reads for every file heoslice reads (meshes, materials, layers).

Anything that is not a regular file (a FIFO, /dev/zero, a directory, a symlink loop) is
one line naming the file, refused before a byte is read, so no read can block forever or
run without end. Reads are bounded: a file larger than its limit is refused from its
size, and one that grows while being read is refused.
"""

from __future__ import annotations

import errno
import os
import stat
from typing import BinaryIO

from heoslice.errors import InputError

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

