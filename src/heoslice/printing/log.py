"""The print log: append-only JSON lines, one object per event, flushed at once (docs/protocol.md section 8)."""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass
from pathlib import Path

from heoslice.errors import OutputError
from heoslice.files import check_output, head_bytes, write_problem


def default_log_path(stack: Path) -> Path:
    """The print log beside a stack directory: ``<stack>.print-log.jsonl``, a path of the form the stack was given in
    (relative stays relative; ``.`` and ``..`` are resolved to be named)."""
    stack = Path(stack)
    stack = stack.resolve() if stack.name in ("", ".", "..") else stack
    return stack.with_name(stack.name + ".print-log.jsonl")


def is_print_log(path: Path) -> bool:
    """Whether ``path`` is a print log heoslice wrote (empty, or its first line an event record): the only
    existing file a print appends to."""
    head = head_bytes(path)
    if not head:
        return os.path.isfile(path) and os.path.getsize(path) == 0
    try:
        first = json.loads(head.split(b"\n", 1)[0])
    except ValueError:
        return False
    return isinstance(first, dict) and {"time", "event"} <= first.keys()


def check_log_output(path: Path, inputs: tuple[Path, ...] = ()) -> None:
    """The output rule for a print log (:func:`heoslice.files.check_output`): a log is appended to, so an
    existing file must be a print log; never a link, a device, the stack or a file inside it. ``print`` has no
    ``--force`` (it appends, replacing nothing), so its refusal of another file does not offer one."""
    if check_output(path, "print log", force=True, made_here=lambda _: True, inputs=inputs) \
            and not is_print_log(path):
        raise OutputError(f"{path}: exists and is not a print log heoslice wrote; print appends only to its own "
                          "logs (remove it yourself, or choose another --log)")


#: Most bytes of a print log read for its last run of a job (a log of thousands of layers is a few MB).
_MOST_LOG_BYTES = 64 << 20


@dataclass(frozen=True)
class LoggedRun:
    """The last run of a job a print log holds: the last layer it logged executed (or, none logged, the layer
    before the one it started at: 0, its --from-layer, or where it resumed) and whether it finished (a ``done``
    record after its ``start``)."""

    last_completed: int
    finished: bool


def last_run(path: Path | None, job_id: int) -> LoggedRun | None:
    """What the print log at ``path`` says of the last run of job ``job_id`` that reached the controller (a run
    refused before it connected leaves the one before as the last), :class:`LoggedRun`; None when it holds none (or
    cannot be read: a print does not fail on its own log's history)."""
    if path is None:
        return None
    try:
        with open(path, "rb") as handle:
            lines = handle.read(_MOST_LOG_BYTES).splitlines()
    except OSError:
        return None
    wanted, run, ours = f"{job_id:08x}", None, False
    for line in lines:
        try:
            record = json.loads(line)
        except ValueError:
            continue
        event = record.get("event") if isinstance(record, dict) else None
        if event == "start":
            ours = record.get("job_id") == wanted
        elif not ours:
            continue
        elif event == "connected" and isinstance(record.get("first_layer"), int):
            run = LoggedRun(record["first_layer"] - 1, False)
        elif run is not None and event == "layer" and isinstance(record.get("layer"), int):
            run = LoggedRun(max(run.last_completed, record["layer"]), False)
        elif run is not None and event == "done":
            run = LoggedRun(run.last_completed, True)
    return run


class PrintLog:
    """A lab's trace of what was printed; ``path`` None writes nothing (an open file handle, so a class)."""

    def __init__(self, path: Path | None):
        self.path = path
        self._handle = None
        if path is not None:
            try:
                descriptor = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC,
                                     0o666)
            except OSError as err:
                raise OutputError(f"{path}: cannot write the print log ({err.strerror})") from err
            self._handle = os.fdopen(descriptor, "a", encoding="utf-8")

    def write(self, event: str, **fields) -> None:
        """Append one event with the UTC time."""
        if self._handle is None:
            return
        record = {"time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"),
                  "event": event, **fields}
        try:
            self._handle.write(json.dumps(record, sort_keys=False) + "\n")
            self._handle.flush()
        except OSError as err:
            self._drop()
            raise write_problem(self.path, err) from None

    def _drop(self) -> None:
        """Close the handle, ignoring what a full disk says about the bytes still buffered."""
        handle, self._handle = self._handle, None
        try:
            handle.close()
        except OSError:
            pass

    def close(self) -> None:
        if self._handle is not None:
            self._drop()
