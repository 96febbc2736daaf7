"""The ending signals as interruptions, one mechanism for every command: SIGINT, SIGTERM and SIGHUP raise
:class:`~heoslice.errors.Interrupted`.

Ctrl-C sends SIGINT, a service manager, ``timeout`` or a CI cancel SIGTERM, a closed terminal SIGHUP.
Raised as a KeyboardInterrupt subclass carrying the signal, they take every path Ctrl-C takes (a print
sends ABORT, a slice stops its workers, an output being written is discarded), and the CLI prints one
line and exits 128 + the signal number. Installed first thing in ``python -m heoslice`` and in the
console script, before the heavy imports, so a signal at any moment ends the command the same way.
"""

from __future__ import annotations

import signal
import threading

from heoslice.errors import Interrupted

#: The signals that end a command: each becomes Interrupted(signum).
TERMINATING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _raise_interrupted(signum: int, frame) -> None:
    """The handler: turn the signal into an exception in the main thread."""
    raise Interrupted(signum)


def interrupt_on_terminating_signals() -> None:
    """Install the handler for SIGINT, SIGTERM and SIGHUP (main thread only; a signal the parent left ignored,
    as ``nohup`` or a shell's background job does, stays ignored)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in TERMINATING_SIGNALS:
        if signal.getsignal(signum) is signal.SIG_IGN:
            continue
        signal.signal(signum, _raise_interrupted)
