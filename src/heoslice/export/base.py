"""What every export format shares: the small writer interface, its options, and an output written safely.

A format is one module in this package defining ``FORMAT``, an :class:`ExportFormat` whose ``write``
turns a verified stack into files handed to a :class:`Sink`. The sink writes into a temporary
folder or zip beside the target and renames it into place only when every file is written, so an
interrupted export never leaves something that looks complete.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from heoslice.errors import InputError, OutputError


@dataclass(frozen=True, slots=True)
class ExportOptions:
    """Format options: target layer pitch (mm) and resolution (dpi x, y), None for the format's default;
    the background colour of empty pixels (None: the format's)."""

    pitch_mm: float | None = None
    dpi: tuple[float, float] | None = None
    background: tuple[int, int, int] | None = None


@dataclass(frozen=True, slots=True)
class ExportFormat:
    """One export format: its name (``--format``), a line of help, and
    ``write(stack directory, verified manifest, sink, options) -> summary dict``."""

    name: str
    summary: str
    write: Callable[[Path, dict, "Sink", ExportOptions], dict]


class Sink:
    """Files of one export: a folder, or a zip when the target ends in ``.zip``; written to a temporary
    name beside the target and moved into place by :meth:`commit`."""

    def __init__(self, target: Path, force: bool = False):
        self.target = Path(target)
        if os.path.lexists(self.target) and not force:
            raise OutputError(f"{self.target}: exists (use --force to overwrite)")
        parent = self.target.parent
        if not parent.is_dir():
            raise OutputError(f"{parent}: no such directory")
        self.is_zip = self.target.suffix.lower() == ".zip"
        try:
            if self.is_zip:
                handle, name = tempfile.mkstemp(prefix=f".{self.target.name}.", suffix=".partial", dir=parent)
                os.close(handle)
                self._temporary = Path(name)
                self._zip = zipfile.ZipFile(self._temporary, "w", compression=zipfile.ZIP_DEFLATED)
            else:
                self._temporary = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.", suffix=".partial",
                                                        dir=parent))
        except OSError as err:
            raise OutputError(f"{self.target}: cannot write ({err.strerror})") from err
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
            raise OutputError(f"{self.target}: cannot write {name} ({err.strerror})") from err
        self.files.append(name)

    def commit(self) -> None:
        """Move the finished export into place (replacing an old one only now)."""
        try:
            if self.is_zip:
                self._zip.close()
                os.chmod(self._temporary, 0o666 & ~_umask())
            else:
                os.chmod(self._temporary, 0o777 & ~_umask())
            if os.path.lexists(self.target):
                if self.target.is_dir() and not self.target.is_symlink():
                    shutil.rmtree(self.target)
                else:
                    self.target.unlink()
            os.replace(self._temporary, self.target)
        except OSError as err:
            self.discard()
            raise OutputError(f"{self.target}: cannot write ({err.strerror})") from err

    def discard(self) -> None:
        """Remove what was written (after a failure)."""
        if self.is_zip:
            try:
                self._zip.close()
            except (OSError, ValueError):
                pass
            Path(self._temporary).unlink(missing_ok=True)
        else:
            shutil.rmtree(self._temporary, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
