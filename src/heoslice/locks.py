"""Stack locks: one process at a time reads a stack for a print or writes it in a slice.

:func:`hold_stack` takes an exclusive ``fcntl.flock`` on the stack directory's own file
descriptor (the directory is created when missing, so a slice can lock it before it exists). The
kernel releases the lock when the holder's descriptor closes, however the process ends
(SIGKILL included), so a lock is never left stale and no lock file is written into the stack.
"""

from __future__ import annotations

import errno
import fcntl
import os
from contextlib import contextmanager
from collections.abc import Iterator
from pathlib import Path

from heoslice.errors import InputError, StackBusyError


@contextmanager
def hold_stack(directory: Path, purpose: str, create: bool = False) -> Iterator[Path]:
    """Hold ``directory`` exclusively while the block runs; StackBusyError (exit 18) when another process holds it.

    ``purpose`` (e.g. "printing", "slicing") is only for the message. ``create`` makes the directory
    (parents too) first. The lock is not re-entrant between separate ``open`` calls of one process.
    """
    directory = Path(directory)
    if create:
        directory.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as err:
        raise InputError(f"{directory}: cannot open the stack for {purpose} ({err.strerror})") from err
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise StackBusyError(f"{directory}: another heoslice process is using this stack (printing or "
                                     f"slicing it); wait for it to finish before {purpose}") from None
            raise InputError(f"{directory}: cannot lock the stack for {purpose} ({err.strerror})") from err
        yield directory
    finally:
        os.close(fd)
