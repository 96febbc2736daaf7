"""The ending signals as interruptions, one mechanism for every command: SIGINT, SIGTERM and SIGHUP raise
:class:`~heoslice.errors.Interrupted`.

Ctrl-C sends SIGINT, a service manager, ``timeout`` or a CI cancel SIGTERM, a closed terminal SIGHUP.
Raised as a KeyboardInterrupt subclass carrying the signal, they take every path Ctrl-C takes (a print
sends ABORT, a slice stops its workers, an output being written is discarded), and the CLI prints one
line and exits 128 + the signal number. Installed first thing in ``python -m heoslice`` and in the
console script, before the heavy imports, so a signal at any moment ends the command the same way; one that
lands while Python runs a finalizer, which drops the exception, is delivered again just after.
"""

from __future__ import annotations

import _thread
import signal
import sys
import threading

from heoslice.errors import Interrupted

#: The signals that end a command: each becomes Interrupted(signum).
TERMINATING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: How long after an interruption Python dropped (raised inside a finalizer or a weakref callback) the signal is
#: delivered again, s: long enough to be back in the command's own code.
REDELIVERY_S = 0.01


def _raise_interrupted(signum: int, frame) -> None:
    """The handler: turn the signal into an exception in the main thread."""
    raise Interrupted(signum)


def _redeliver_dropped(unraisable) -> None:
    """sys.unraisablehook: an Interrupted raised while Python ran a finalizer or a weakref callback is printed
    and dropped there ("Exception ignored in ..."), and the command would go on to finish; deliver its signal
    again a moment later, in the main thread, instead. Anything else goes to the hook before."""
    if isinstance(unraisable.exc_value, Interrupted):
        timer = threading.Timer(REDELIVERY_S, _thread.interrupt_main, args=(unraisable.exc_value.signum,))
        timer.daemon = True
        timer.start()
        return
    _previous_hook(unraisable)


_previous_hook = sys.unraisablehook


def interrupt_on_terminating_signals() -> None:
    """Install the handler for SIGINT, SIGTERM and SIGHUP (main thread only; a signal the parent left ignored,
    as ``nohup`` or a shell's background job does, stays ignored)."""
    if threading.current_thread() is not threading.main_thread():
        return
    sys.unraisablehook = _redeliver_dropped
    for signum in TERMINATING_SIGNALS:
        if signal.getsignal(signum) is signal.SIG_IGN:
            continue
        signal.signal(signum, _raise_interrupted)
