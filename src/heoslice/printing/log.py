"""The print log: append-only JSON lines, one object per event, flushed at once (docs/protocol.md section 8)."""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path

from heoslice.errors import OutputError


def default_log_path(stack: Path) -> Path:
    """The print log beside a stack directory: ``<stack>.print-log.jsonl``, a path of the form the stack was given in
    (relative stays relative; ``.`` and ``..`` are resolved to be named)."""
    stack = Path(stack)
    stack = stack.resolve() if stack.name in ("", ".", "..") else stack
    return stack.with_name(stack.name + ".print-log.jsonl")


class PrintLog:
    """A lab's trace of what was printed; ``path`` None writes nothing (an open file handle, so a class)."""

    def __init__(self, path: Path | None):
        self.path = path
        self._handle = None
        if path is not None:
            try:
                self._handle = open(path, "a", encoding="utf-8")
            except OSError as err:
                raise OutputError(f"{path}: cannot write the print log ({err.strerror})") from err

    def write(self, event: str, **fields) -> None:
        """Append one event with the UTC time."""
        if self._handle is None:
            return
        record = {"time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"),
                  "event": event, **fields}
        self._handle.write(json.dumps(record, sort_keys=False) + "\n")
        self._handle.flush()

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None
