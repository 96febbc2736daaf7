"""What every export format shares: the small writer interface, its options, and an output written safely.

A format is one module in this package defining ``FORMAT``, an :class:`ExportFormat` whose ``write``
turns a verified stack into files handed to a :class:`Sink`. The sink writes into a partial
folder or zip beside the target and renames it into place only when every file is written, so an
interrupted export never leaves something that looks complete.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from heoslice.errors import InputError, OutputError
from heoslice.files import check_output, discard_partial, head_bytes, move_into_place, partial_path, write_problem
from heoslice.stack.verify import StackPlan

#: Output names written as one zip file rather than a folder (a GrabCAD Voxel Print File is a zip).
ZIP_SUFFIXES = (".zip", ".gcvf")


@dataclass(frozen=True, slots=True)
class ExportOptions:
    """Format options: target layer pitch (mm) and resolution (dpi x, y), None for the format's default;
    the background colour of empty pixels (None: the format's)."""

    pitch_mm: float | None = None
    dpi: tuple[float, float] | None = None
    background: tuple[int, int, int] | None = None


@dataclass(frozen=True, slots=True)
class ExportFormat:
    """One export format: its name (``--format``), a line of help, and ``write(stack, sink, options) -> summary
    dict``, ``stack`` a :class:`heoslice.stack.verify.StackPlan` checked as a whole, whose every layer ``write``
    reads through :func:`heoslice.stack.verify.verified_layer`, which checks it."""

    name: str
    summary: str
    write: Callable[[StackPlan, "Sink", ExportOptions], dict]
    takes: frozenset[str] = frozenset({"pitch_mm", "dpi", "background"})  # the ExportOptions fields it uses



#: Marks an export heoslice wrote (the only kind ``export --force`` replaces): a hidden file in a folder
#: export, the comment of a zip export.
EXPORT_MARK = ".heoslice-export"
ZIP_COMMENT = b"heoslice export"


def is_export(path: Path) -> bool:
    """Whether ``path`` is an export heoslice wrote: a folder holding EXPORT_MARK, or a zip with ZIP_COMMENT."""
    path = Path(path)
    if path.is_dir():
        return (path / EXPORT_MARK).is_file() and not (path / EXPORT_MARK).is_symlink()
    if not head_bytes(path, 4).startswith(b"PK"):
        return False
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.comment == ZIP_COMMENT
    except (zipfile.BadZipFile, OSError, ValueError):
        return False


class Sink:
    """Files of one export: a folder, or a zip when the target ends in ``.zip`` or ``.gcvf``; written to a partial name
    beside the target and moved into place by :meth:`commit` (the output rule of :mod:`heoslice.files`)."""

    def __init__(self, target: Path, force: bool = False, inputs: tuple[Path, ...] = ()):
        self.target = Path(target)
        self.is_zip = self.target.suffix.lower() in ZIP_SUFFIXES
        check_output(self.target, "export", force=force, made_here=is_export, inputs=inputs, folder=not self.is_zip)
        parent = self.target.parent if str(self.target.parent) else Path(".")
        if not parent.is_dir():
            raise OutputError(f"{parent}: no such directory")
        self._temporary = partial_path(self.target, folder=not self.is_zip)
        if self.is_zip:
            try:
                self._zip = zipfile.ZipFile(self._temporary, "w", compression=zipfile.ZIP_DEFLATED)
                self._zip.comment = ZIP_COMMENT
            except OSError as err:
                discard_partial(self._temporary)
                raise write_problem(self.target, err) from err
        self.files: list[str] = []
        #: ``progress(done, total)`` a format reports its layers to (:meth:`progress`), when the caller sets it.
        self.on_progress: Callable[[int, int], None] | None = None

    def progress(self, done: int, total: int) -> None:
        """A format has written ``done`` of its ``total`` layers (or slices)."""
        if self.on_progress is not None:
            self.on_progress(done, total)

    def add(self, name: str, data: bytes) -> None:
        """Write one file of the export."""
        try:
            if self.is_zip:
                self._zip.writestr(name, data)
            else:
                (self._temporary / name).write_bytes(data)
        except OSError as err:
            self.discard()
            raise write_problem(f"{self.target}/{name}", err) from err
        self.files.append(name)

    def commit(self) -> None:
        """Move the finished export into place (replacing an old export only now)."""
        try:
            if self.is_zip:
                self._zip.close()
            else:
                (self._temporary / EXPORT_MARK).write_text("written by heoslice export\n")
        except OSError as err:
            self.discard()
            raise write_problem(self.target, err) from err
        move_into_place(self._temporary, self.target, folder=not self.is_zip)

    def discard(self) -> None:
        """Remove what was written (after a failure)."""
        if self.is_zip:
            try:
                self._zip.close()
            except (OSError, ValueError):
                pass
        discard_partial(self._temporary)


def check_options(options: ExportOptions) -> None:
    """Range-check the options (InputError naming the parameter)."""
    if options.pitch_mm is not None and not 0.001 <= options.pitch_mm <= 1.0:
        raise InputError(f"pitch_mm: must be from 0.001 to 1 mm, not {options.pitch_mm:g}")
    if options.dpi is not None and not all(10.0 <= d <= 10_000.0 for d in options.dpi):
        raise InputError(f"dpi: each resolution must be from 10 to 10000 dpi, "
                         f"not {options.dpi[0]:g} x {options.dpi[1]:g}")
    if options.background is not None and not (len(options.background) == 3
                                               and all(0 <= v <= 255 for v in options.background)):
        raise InputError("background: must be three integers 0..255")
