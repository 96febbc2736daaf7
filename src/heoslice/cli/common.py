"""Helpers shared by the sub-commands: warnings, progress, the exit-status epilog, JSON output, several inputs.

The JSON convention (every command's ``--json``): exactly one JSON value on stdout,
on one line; one object per input, a list of them when the command was given several
inputs (or a pattern); every object has ``"ok"``; a failed input in a list is
``{KEY: input, "ok": false, "error": line, "exit_code": N}``; no NaN or Infinity
(``null`` instead). The exit status is the same as without ``--json``.
"""

from __future__ import annotations

import glob
import json
import math
import os
import sys
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import click

from heoslice.errors import (
    EXIT_BUG,
    EXIT_CODES,
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    HeosliceError,
)

#: Characters that make a MODEL argument a pattern for heoslice to expand (when no file has that name).
GLOB_CHARACTERS = frozenset("*?[")


def echo_warnings(source: Path, warnings: tuple[str, ...] | list[str]) -> None:
    """One ``warning: FILE: text`` line per warning, on stderr."""
    for text in warnings:
        click.echo(f"warning: {source}: {text}", err=True)


def progress_shown(enabled: bool = True) -> bool:
    """Whether a progress bar is drawn: on a terminal (stderr a tty) only, never with ``--json`` (``enabled``
    False) nor under CI (the ``CI`` variable set, as CI services set it), so pipes and logs stay clean."""
    return enabled and sys.stderr.isatty() and not os.environ.get("CI")


@contextmanager
def progress_bar(description: str, unit: str = "layer",
                 enabled: bool = True) -> Iterator[Callable[..., None]]:
    """The one progress display of every command: a ``progress(done, total, note=None)`` callback drawing a tqdm
    bar (count, rate and time left; ``note`` after them) where :func:`progress_shown`, silent otherwise. The bar
    appears at the first call, redraws at every call (so it moves per layer or item) and is erased when
    ``done`` reaches ``total`` or the block ends, so that phases (verify, then write) follow on one line.
    tqdm is imported only to draw one: a pipeline's run, logged to a file, does not load it."""
    if not progress_shown(enabled):
        yield lambda done, total, note=None: None
        return
    from tqdm import tqdm

    bars: list = []

    try:  # a terminal that reports no size (0 x 0: some pseudo-terminals) gets a bar of 80 columns, 24 rows (tqdm
        sized = min(os.get_terminal_size(sys.stderr.fileno())) > 0  # hides a bar below a screen of 0 rows)
    except OSError:
        sized = False

    def update(done: int, total: int, note: str | None = None) -> None:
        if not bars:
            bars.append(tqdm(desc=description, unit=unit, total=total, leave=False, dynamic_ncols=sized,
                             ncols=None if sized else 80, nrows=None if sized else 24, file=sys.stderr,
                             mininterval=0, miniters=1))
        bar = bars[0]
        if bar.disable:
            return
        bar.total = total
        if note is not None:
            bar.set_postfix_str(note, refresh=False)
        bar.update(done - bar.n)
        if done >= total:
            bar.close()

    try:
        yield update
    finally:
        for bar in bars:
            bar.close()


# --- message formatting ------------------------------------------------------------------------------------

def plural(count: int, noun: str, plural_form: str | None = None) -> str:
    """'1 layer', '0 layers', '3 layers' (``plural_form`` for nouns that do not take an s)."""
    return f"{count} {noun if count == 1 else plural_form or noun + 's'}"


def signed_percent(fraction: float, digits: int = 2) -> str:
    """A relative difference as '+1.25 %' / '-0.40 %'; one that rounds to zero is '0.00 %', never '-0.00 %'."""
    text = f"{100 * fraction:+.{digits}f}"
    return f"{text[1:] if float(text) == 0 else text} %"


def exit_status_epilog(codes: tuple[int, ...] | list[int]) -> str:
    """The 'Exit status:' paragraph of a command's help, its meanings read from errors.EXIT_CODES."""
    width = max(len(str(code)) for code in codes)
    lines = [f"  {code:<{width}}  {EXIT_CODES[code]}" for code in sorted(codes)]
    return "\b\nExit status:\n" + "\n".join(lines) + "\n"


def error_line(err: BaseException, debug: bool = False) -> tuple[str, int]:
    """The one stderr line and the exit status for an error: a HeosliceError is the user's, anything else a bug."""
    if debug:
        traceback.print_exception(err)
    if isinstance(err, HeosliceError):
        return f"heoslice: error: {err}", err.exit_code
    return (f"heoslice: internal error: {type(err).__name__}: {err} "
            "(rerun with --debug and report the traceback)", EXIT_BUG)


# --- JSON output -------------------------------------------------------------------------------------------

def json_option(function: Callable) -> Callable:
    """The ``--json`` flag every command shares (parameter ``as_json``)."""
    flag = click.option("--json", "as_json", is_flag=True,
                        help="Print one JSON value on stdout instead of text (see the README's JSON section).")
    return flag(function)


def _plain(value: object) -> object:
    """``value`` with paths as strings, tuples as lists, numpy scalars as numbers and non-finite floats as None."""
    if isinstance(value, dict):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "item") and callable(value.item) and getattr(value, "shape", None) == ():
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def echo_json(value: object) -> None:
    """Write ``value`` as one line of strict JSON on stdout (the convention in this module's docstring)."""
    click.echo(json.dumps(_plain(value), allow_nan=False))
    sys.stdout.flush()


# --- several inputs per call -------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Inputs:
    """The files one call works on, in the order given, after heoslice expanded the patterns.

    ``items`` holds each file once, in order, and (as a ``str``) each pattern that
    matched no file, where it was given. ``several`` is true when more than one
    argument or any pattern was given: then the command reports per input and its JSON
    is a list, however many files matched.
    """

    items: tuple[Path | str, ...]
    several: bool

    @property
    def paths(self) -> tuple[Path, ...]:
        """The files, in order."""
        return tuple(item for item in self.items if isinstance(item, Path))


def expand_inputs(arguments: tuple[Path, ...] | list[Path]) -> Inputs:
    """Expand glob patterns (``scans/*.ply``, ``**`` recursive) the shell left alone; drop repeats, keep order.

    An argument naming an existing file is taken literally even if it has glob
    characters, so a file called ``a[1].ply`` is still found.
    """
    items: list[Path | str] = []
    pattern_given = False
    for argument in arguments:
        text = str(argument)
        if GLOB_CHARACTERS.isdisjoint(text) or Path(text).exists():
            items.append(Path(text))
            continue
        pattern_given = True
        matches = sorted(match for match in glob.glob(text, recursive=True) if Path(match).is_file())
        items += [Path(match) for match in matches] or [text]
    return Inputs(items=tuple(dict.fromkeys(items)), several=len(arguments) > 1 or pattern_given)


def run_each(inputs: Inputs, run: Callable[[Path], dict], key: str, as_json: bool, debug: bool = False) -> None:
    """Run ``run(path) -> summary`` for every input; a failing one gives its line and the others still run.

    With one literal input its error propagates as usual. With several, each failure
    (a pattern matching nothing included) is one ``heoslice: error:`` line on stderr,
    then one line saying how many failed, and the exit status is the highest of theirs.
    A Ctrl-C (or an error with the interrupted status) stops the whole call. With
    ``as_json`` the summaries and failure entries are printed as one JSON list, in the
    order given.
    """
    if not inputs.several:
        summary = run(inputs.paths[0])
        if as_json:
            echo_json(summary)
        return
    entries: list[dict] = []
    failed: list[tuple[str, int]] = []
    for item in inputs.items:
        try:
            if isinstance(item, str):
                raise HeosliceError(f"{item}: no file matches this pattern", exit_code=EXIT_INPUT)
            entries.append(run(item))
        except Exception as err:  # noqa: BLE001 - one input's failure, reported as main() would
            if isinstance(err, HeosliceError) and err.exit_code == EXIT_INTERRUPTED:
                raise
            line, code = error_line(err, debug)
            click.echo(line, err=True)
            message = str(err) if isinstance(err, HeosliceError) else line
            entries.append({key: str(item), "ok": False, "error": message, "exit_code": code})
            failed.append((str(item), code))
    if as_json:
        echo_json(entries)
    if failed:
        names = ", ".join(name for name, _ in failed[:5]) + (", ..." if len(failed) > 5 else "")
        raise HeosliceError(f"{len(failed)} of {len(inputs.items)} {key}s failed: {names}",
                            exit_code=max(code for _, code in failed))
