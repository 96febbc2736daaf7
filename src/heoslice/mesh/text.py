"""Tokenising ASCII mesh bodies (PLY, OFF) with numpy: numbers, the rows they form, the line each came from."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from heoslice.errors import InputError

#: Longest ASCII token accepted in a PLY body (a double needs at most 24 characters).
MAX_TOKEN = 64


def ascii_rows(path: Path, body: bytes, first_line: int):
    """Parse an ASCII body (PLY or OFF): (values (t,) float64, and per non-empty line: first value, value count, line number)."""
    data = np.frombuffer(body, dtype=np.uint8)
    space = np.zeros(256, dtype=bool)
    space[[9, 10, 11, 12, 13, 32]] = True
    blank = space[data]
    starts = np.flatnonzero(~blank & np.concatenate([[True], blank[:-1]]))
    stops = np.flatnonzero(~blank & np.concatenate([blank[1:], [True]])) + 1
    newlines = np.flatnonzero(data == 10)  # line numbers from newline positions, not a count per byte

    def line_at(position: int) -> int:
        return first_line + int(np.searchsorted(newlines, position))

    too_long = np.flatnonzero(stops - starts > MAX_TOKEN)
    if len(too_long):
        raise InputError(f"{path}: line {line_at(int(starts[too_long[0]]))}: "
                         f"value longer than {MAX_TOKEN} characters")
    if np.any(data > 126):
        raise InputError(f"{path}: line {line_at(int(np.argmax(data > 126)))}: non-ASCII byte in an ASCII body")
    values = None
    if len(starts):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                values = np.fromstring(body.decode("ascii"), dtype=np.float64, sep=" ")
            except (ValueError, DeprecationWarning):
                values = None
    else:
        values = np.zeros(0)
    if values is None or len(values) != len(starts):
        bad = int(starts[min(0 if values is None else len(values), len(starts) - 1)])
        for start, stop in zip(starts, stops):  # locate the first bad token for the message (error path only)
            try:
                float(body[start:stop])
            except ValueError:
                bad = int(start)
                break
        token = body[bad:bad + MAX_TOKEN].split()[0].decode("ascii", "replace")
        raise InputError(f"{path}: line {line_at(bad)}: {token[:40]!r} is not a number")
    token_line = np.searchsorted(newlines, starts) if len(starts) else np.zeros(0, dtype=np.int64)
    lines, row_start, row_length = np.unique(token_line, return_index=True, return_counts=True)
    return values, row_start, row_length, lines + first_line


def as_type(path: Path, values: np.ndarray, kind: str, where: np.ndarray, what: str) -> np.ndarray:
    """ASCII values converted to the declared PLY type; fractions and out-of-range integers are refused."""
    if kind[0] == "f":
        with np.errstate(over="ignore"):  # out of float32 range becomes inf, refused later for coordinates
            return values.astype(kind)
    info = np.iinfo(kind)
    with np.errstate(invalid="ignore"):
        bad = (~np.isfinite(values) | (values != np.round(values))
               | (values < float(info.min)) | (values >= float(info.max) + 1.0))  # exact powers of two
    if bad.any():
        first = int(np.argmax(bad))
        raise InputError(f"{path}: line {where[first]}: {what} {float(values[first]):.15g} is not a "
                         f"{np.dtype(kind).name} (a whole number {info.min}..{info.max})")
    return values.astype(kind)

