"""User-facing errors: one line of text and a documented process exit status.

Library code raises these; the CLI prints ``heoslice: error: <message>`` and exits
with ``exit_code``. Anything else reaching the CLI is a bug (exit 1, traceback
only with ``--debug``).
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_BUG = 1
EXIT_INPUT = 2  # bad input file, bad option value (click usage errors also exit 2)
EXIT_OUTPUT = 3  # output cannot be written: exists, unwritable, disk full
EXIT_VERIFY = 4  # a stack failed verification
EXIT_INTERRUPTED = 130  # Ctrl-C (SIGINT); any signal ends with 128 + its number (SIGHUP 129, SIGTERM 143)
EXIT_STACK_BUSY = 18  # another process holds the stack (a print, or a slice writing it)
EXIT_HANGUP = 129  # SIGHUP
EXIT_TERMINATED = 143  # SIGTERM
EXIT_PIPE = 141  # the reader of the output went away (`heoslice verify STACK | head`): 128 + SIGPIPE, as a shell
#                 reports a writer that a closed pipe ended


def shown(value, limit: int = 40) -> str:
    """``value`` for a one-line message: its repr, numpy scalars and arrays as plain Python numbers (never
    ``np.float64(...)``), cut to ``limit`` characters."""
    text = repr(value)
    if hasattr(value, "dtype") and hasattr(value, "tolist"):
        more = getattr(value, "size", 1) > 8
        text = repr(value.ravel()[:8].tolist() if getattr(value, "ndim", 0) else value.tolist())
        text = text[:-1] + ", ...]" if more else text
    return text if len(text) <= limit else text[: limit - 3] + "..."


class Interrupted(KeyboardInterrupt):
    """A terminating signal (SIGTERM, SIGHUP) delivered as an interruption, so every Ctrl-C path handles it.

    ``exit_code`` is 128 + the signal number, the shell's convention.
    """

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
        self.exit_code = 128 + signum


class HeosliceError(Exception):
    """An error the user can act on; ``str(err)`` is the whole one-line message."""

    exit_code = EXIT_INPUT

    def __init__(self, message: str, exit_code: int | None = None):
        super().__init__(" ".join(str(message).split()))
        if exit_code is not None:
            self.exit_code = exit_code


class InputError(HeosliceError):
    """An input file or option value is unusable."""

    exit_code = EXIT_INPUT


class MalformedDesign(InputError):
    """A design record that cannot be read (a stack's manifest or a model's header): unknown version, kind or
    function, a field missing or of the wrong type."""


class OutputError(HeosliceError):
    """The output cannot be written."""

    exit_code = EXIT_OUTPUT


class VerifyError(HeosliceError):
    """A stack on disk is incomplete, altered or malformed."""

    exit_code = EXIT_VERIFY


# --- printer link (issue 5): exit codes and errors of `heoslice print` --------------------
# Documented in docs/protocol.md ("Exit codes").

EXIT_PORT = 10  # the port cannot be opened (no such device, permission, refused connection)
EXIT_LINK_DEAD = 11  # no frame from the controller for too long, reconnecting failed
EXIT_PROTOCOL = 12  # protocol version mismatch, no controller answering, or a job it cannot print
EXIT_RETRIES = 13  # retry cap reached; the job was paused on the controller
EXIT_RESET = 14  # the controller was reset (new boot id) during the print: rerun with --from-layer
EXIT_CONTROLLER = 15  # the controller reported an error (layer CRC mismatch, hardware fault)
EXIT_BUSY = 16  # another host is printing on this controller
EXIT_UNFINISHED = 17  # the controller holds an unfinished job: --resume or --restart
EXIT_STACK_CHANGED = 19  # a file of the stack changed while it was being printed
EXIT_FINISHED = 20  # the controller just finished this very job: --restart prints it again on purpose


class ProtocolError(HeosliceError):
    """Bytes that are not a valid frame or message of the printer protocol."""

    exit_code = EXIT_PROTOCOL


class PrinterError(HeosliceError):
    """A print could not be completed; ``exit_code`` names the failure class."""

    exit_code = EXIT_LINK_DEAD


class PortError(PrinterError):
    """The printer port cannot be opened."""

    exit_code = EXIT_PORT


class LinkDeadError(PrinterError):
    """The controller stopped answering and could not be reached again."""

    exit_code = EXIT_LINK_DEAD


class IncompatibleControllerError(PrinterError):
    """The controller speaks another protocol version, or cannot print this job."""

    exit_code = EXIT_PROTOCOL


class RetryLimitError(PrinterError):
    """A frame was retransmitted too often without progress; the job was paused."""

    exit_code = EXIT_RETRIES


class ControllerResetError(PrinterError):
    """The controller rebooted during the print; ``next_layer`` is where to resume after checking the part."""

    exit_code = EXIT_RESET

    def __init__(self, message: str, next_layer: int):
        super().__init__(message)
        self.next_layer = next_layer


class ControllerFaultError(PrinterError):
    """The controller reported an error state."""

    exit_code = EXIT_CONTROLLER


class ControllerBusyError(PrinterError):
    """Another host holds the controller with a job in progress; nothing was changed."""

    exit_code = EXIT_BUSY


class UnfinishedJobError(PrinterError):
    """The controller holds an unfinished job; the user must say --resume or --restart."""

    exit_code = EXIT_UNFINISHED


class FinishedJobError(PrinterError):
    """The controller reports this very job as finished by an earlier run; nothing was sent."""

    exit_code = EXIT_FINISHED


class StackBusyError(HeosliceError):
    """Another process holds the stack directory (a print reading it, or a slice writing it)."""

    exit_code = EXIT_STACK_BUSY


class StackChangedError(PrinterError):
    """A file of the stack changed while the stack was being printed; ABORT was sent."""

    exit_code = EXIT_STACK_CHANGED


class PrintInterrupted(PrinterError):
    """The user interrupted the print (Ctrl-C, SIGTERM, SIGHUP); ABORT was sent to the controller."""

    exit_code = EXIT_INTERRUPTED


#: Every exit status heoslice uses -> what it means, for the help texts and the README (one source of the numbers).
EXIT_CODES: dict[int, str] = {
    EXIT_OK: "success",
    EXIT_BUG: "a bug in heoslice (rerun with --debug and report the traceback)",
    EXIT_INPUT: "bad input: a file that cannot be read or a bad option value",
    EXIT_OUTPUT: "the output cannot be written (exists, unwritable, disk full)",
    EXIT_VERIFY: "a stack failed verification",
    EXIT_PORT: "the printer port cannot be opened",
    EXIT_LINK_DEAD: "the link died: no frame from the controller, reconnecting failed",
    EXIT_PROTOCOL: "protocol version mismatch, no controller answering, or a job it cannot print",
    EXIT_RETRIES: "retry limit reached; the job was paused on the controller",
    EXIT_RESET: "the controller was reset during the print: rerun with --from-layer",
    EXIT_CONTROLLER: "the controller reported an error (layer CRC mismatch, hardware fault)",
    EXIT_BUSY: "the controller is busy with another host",
    EXIT_UNFINISHED: "the controller holds an unfinished job: rerun with --resume or --restart",
    EXIT_STACK_BUSY: "another heoslice process holds the stack (a print, or a slice writing it)",
    EXIT_STACK_CHANGED: "a file of the stack changed while it was being printed",
    EXIT_FINISHED: "the controller already finished this job: rerun with --restart to print it again",
    EXIT_HANGUP: "hung up (SIGHUP); a print sends ABORT first",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C); a print sends ABORT first",
    EXIT_PIPE: "the reader of the output went away (a closed pipe, as in | head)",
    EXIT_TERMINATED: "terminated (SIGTERM); a print sends ABORT first",
}
