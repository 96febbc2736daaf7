"""Stacks to other printers' formats: one module per format (``png``, ``voxel_print``), each defining a
``FORMAT`` behind the small writer interface of :mod:`heoslice.export.base`; a new format is one new module.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from pathlib import Path

from heoslice.errors import InputError
from heoslice.export.base import ExportFormat, ExportOptions, Sink, check_options
from heoslice.stack.verify import open_verified


def formats() -> dict[str, ExportFormat]:
    """Every export format of this package, by name: the ``FORMAT`` of each module beside ``base``."""
    found = {}
    for module in sorted(info.name for info in pkgutil.iter_modules(__path__)):
        if module != "base":
            fmt = getattr(importlib.import_module(f"{__name__}.{module}"), "FORMAT", None)
            if isinstance(fmt, ExportFormat):
                found[fmt.name] = fmt
    return found


def export_stack(directory: Path, format_name: str, output: Path, options: ExportOptions = ExportOptions(),
                 force: bool = False, writing: Callable[[int, int], None] | None = None) -> dict:
    """Write the stack in ``directory`` as ``format_name`` to ``output`` (a folder, or a zip when it ends in
    .zip), checking it as :func:`heoslice.stack.verify_stack` does while it is read, in one pass: the stack as
    a whole before anything is written, each layer as the format reads it (every layer is read). A problem
    stops the export and removes what was written, leaving ``output`` as it was. Return the format's summary
    with the files written; ``writing(done, total)`` follows the layers (for a progress bar)."""
    known = formats()
    if format_name not in known:
        raise InputError(f"format: unknown export format {format_name!r}; choose from {', '.join(known)}")
    check_options(options)
    unused = [name for name in ("pitch_mm", "dpi", "background")
              if getattr(options, name) is not None and name not in known[format_name].takes]
    if unused:
        raise InputError(f"{unused[0]}: --format {format_name} does not use it (it writes the stack's own "
                         "resolution and colours)")
    stack = open_verified(Path(directory))
    sink = Sink(output, force=force, inputs=(Path(directory),))
    sink.on_progress = writing
    try:
        summary = known[format_name].write(stack, sink, options)
        sink.commit()  # inside: a signal while the output is closed or moved into place discards it too
    except BaseException:
        sink.discard()
        raise
    return {"stack": str(directory), "format": format_name, "output": str(output), "files": len(sink.files),
            **summary}


__all__ = ["ExportFormat", "ExportOptions", "Sink", "export_stack", "formats"]
