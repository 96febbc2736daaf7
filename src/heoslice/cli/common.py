"""Helpers shared by the sub-commands: warnings and progress on a terminal."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import click


def echo_warnings(source: Path, warnings: tuple[str, ...] | list[str]) -> None:
    """One ``warning: FILE: text`` line per warning, on stderr."""
    for text in warnings:
        click.echo(f"warning: {source}: {text}", err=True)


@contextmanager
def progress_bar(description: str, unit: str = "it") -> Iterator[Callable[[int, int], None]]:
    """A ``progress(done, total)`` callback drawing a tqdm bar on a terminal, silent otherwise."""
    from tqdm import tqdm

    if not sys.stderr.isatty():
        yield lambda done, total: None
        return
    bar = tqdm(desc=description, unit=unit, leave=False, dynamic_ncols=True, file=sys.stderr)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()
