"""Terminating signals as interruptions: SIGTERM and SIGHUP raise :class:`~heoslice.errors.Interrupted`.

A service manager, ``timeout`` or a CI cancel ends a process with SIGTERM, a closed terminal with
SIGHUP. Raised as a KeyboardInterrupt subclass, they take every path Ctrl-C takes (a print sends
ABORT, a slice cleans up), and the CLI exits 128 + the signal number.
"""

from __future__ import annotations

import signal
import threading

from heoslice.errors import Interrupted

#: The signals handled like Ctrl-C (SIGINT keeps Python's own KeyboardInterrupt).
TERMINATING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


def _raise_interrupted(signum: int, frame) -> None:
    """The handler: turn the signal into an exception in the main thread."""
    raise Interrupted(signum)


def interrupt_on_terminating_signals() -> None:
    """Install the handler for SIGTERM and SIGHUP (main thread only; a signal already ignored stays ignored)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in TERMINATING_SIGNALS:
        if signal.getsignal(signum) is signal.SIG_IGN:
            continue
        signal.signal(signum, _raise_interrupted)
