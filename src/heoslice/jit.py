"""How the compiled kernels are chosen, and the one conversion of their array arguments.

The kernels are written once, as numba functions in the ``*_kernels`` modules beside the code they speed up
(the weld's, the edge grouping's and the shells' in ``mesh``; the slicing's, the chaining's and the
rasteriser's in ``layers``; the surface distance's in ``material``; the grading's in ``grading``; Voxel
Print's run stream in ``export``). Installing heoslice compiles them ahead of time
into the extension modules ``heoslice._compiled`` and ``heoslice._compiled_b`` (a share each, compiled side by side) (:mod:`heoslice.kernel_exports`, run by ``setup.py``), so
that a slice loads neither numba nor LLVM: they cost every process of a slice its largest fixed share of
memory and start-up time (benchmarks/README.md). :func:`kernel` hands each module the compiled function
when that extension was built from these very sources (its digest matches), else numba's just-in-time
compilation of the same function, as it does whenever ``HEOSLICE_JIT=1`` (the ahead-of-time build itself,
and tests that compare the two). :func:`helper` marks a function that only kernels call: compiled into
them, plain Python otherwise.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Compiled with fast-math's reassociation and contraction (to vectorise), not its no-inf/no-NaN
#: assumptions: distances start at inf.
JIT = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"nsz", "arcp", "contract", "reassoc"}}
#: The halftone reproduces the float32 arithmetic of the dither exactly: no contraction or reassociation.
EXACT = {"cache": True, "nogil": True, "error_model": "numpy"}

#: The environment variable that makes the kernels compile just in time with numba, whatever is installed.
JIT_VARIABLE = "HEOSLICE_JIT"
#: The environment variable that makes every compiled kernel check its arguments' types and layout first.
CHECK_VARIABLE = "HEOSLICE_CHECK_KERNELS"
#: The extension modules the ahead-of-time build writes, each with a share of the kernels (compiled side by side,
#: one process each: :data:`heoslice.kernel_exports.SECOND_MODULE_KERNELS`), and each module's exports of its
#: sources' digest and of its kernels' argument layouts (JSON: export name -> one layout per argument).
COMPILED_MODULES = ("heoslice._compiled", "heoslice._compiled_b")
DIGEST_EXPORT, LAYOUTS_EXPORT = "source_digest", "argument_layouts"
#: Label widths (bits) a kernel taking a label array is exported for, labels unsigned: uint8 (a layer of
#: few sub-regions: half the memory traffic of its per-pixel passes), uint16, and uint32 past 65535
#: (:func:`heoslice.grading.field.label_dtype`).
LABEL_BITS = (8, 16, 32)


@dataclass(frozen=True)
class Entry:
    """A kernel that Python calls, as numba compiles it just in time: what the export table exports."""

    dispatcher: Callable
    label_arg: int | None


#: Every kernel decorated while kernels compile just in time, in import order.
ENTRIES: list[Entry] = []


def kernel_sources() -> list[Path]:
    """Every module the compiled kernels are made from: this one, the export table and each stage's
    ``*_kernels`` modules, in a fixed order."""
    package = Path(__file__).parent
    return [Path(__file__), package / "kernel_exports.py", *sorted(package.glob("*/*_kernels.py"))]


def source_digest() -> int:
    """A 60-bit digest of :func:`kernel_sources`, so that an extension built from other sources is never
    used."""
    package = Path(__file__).parent
    digest = hashlib.sha256()
    for path in kernel_sources():
        digest.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return int(digest.hexdigest()[:15], 16)


def _enabled(variable: str) -> bool:
    """Whether an environment variable is set to anything but empty or 0."""
    return os.environ.get(variable, "") not in ("", "0")


@dataclass(frozen=True)
class CompiledKernels:
    """The ahead-of-time compiled kernels: the extension modules of COMPILED_MODULES, each holding a share of
    the exports; an export is an attribute, found in whichever module holds it."""

    modules: tuple

    def __getattr__(self, name: str):
        for module in self.modules:
            if hasattr(module, name):
                return getattr(module, name)
        raise AttributeError(f"no compiled kernel {name!r}")

    def source_digest(self) -> int:
        """The digest of the sources the modules were built from (the same in each, checked on loading)."""
        return getattr(self.modules[0], DIGEST_EXPORT)()

    def argument_layouts(self) -> str:
        """Every module's export layouts, merged (JSON: export name -> one layout per argument)."""
        merged = {}
        for module in self.modules:
            merged.update(json.loads(getattr(module, LAYOUTS_EXPORT)()))
        return json.dumps(merged)


@functools.cache
def compiled_module() -> CompiledKernels | None:
    """The ahead-of-time compiled kernels, or None: a module not built, one built from other sources, or
    HEOSLICE_JIT=1."""
    if _enabled(JIT_VARIABLE):
        return None
    try:
        modules = tuple(importlib.import_module(name) for name in COMPILED_MODULES)
    except ImportError:
        return None
    digest = source_digest()
    return CompiledKernels(modules) if all(getattr(m, DIGEST_EXPORT)() == digest for m in modules) else None


@functools.cache
def _argument_layouts() -> dict:
    """Every export's argument layouts, read once from the extension (HEOSLICE_CHECK_KERNELS only)."""
    return json.loads(compiled_module().argument_layouts())


def _compiled_export(name: str) -> Callable:
    """The compiled kernel ``name``; with HEOSLICE_CHECK_KERNELS=1, wrapped to refuse (TypeError) arguments
    that differ from its signature, which the compiled code would misread rather than refuse."""
    compiled = compiled_module()
    export = getattr(compiled, name)
    if not _enabled(CHECK_VARIABLE):
        return export
    wanted = _argument_layouts()[name]

    @functools.wraps(export)
    def checked(*args):
        if len(args) != len(wanted):
            raise TypeError(f"{name}: {len(args)} arguments, not {len(wanted)}")
        for position, (value, layout) in enumerate(zip(args, wanted)):
            problem = layout_problem(value, layout)
            if problem:
                raise TypeError(f"{name}: argument {position}: {problem}")
        return export(*args)

    return checked


def layout_problem(value, layout) -> str | None:
    """How ``value`` differs from an export's argument layout (:func:`heoslice.kernel_exports.layout_of`:
    "DTYPE NDIMd" an array, "int", "float" or "bool" a scalar, a list a tuple), or None."""
    if isinstance(layout, list):
        if not isinstance(value, tuple) or len(value) != len(layout):
            return f"{type(value).__name__}, not a tuple of {len(layout)}"
        for index, (item, item_layout) in enumerate(zip(value, layout)):
            problem = layout_problem(item, item_layout)
            if problem:
                return f"item {index}: {problem}"
        return None
    if " " in layout:
        if not isinstance(value, np.ndarray):
            return f"{type(value).__name__}, not an array"
        found = f"{value.dtype} {value.ndim}d"
        if found != layout or not value.flags.c_contiguous:
            return f"{found} {'C' if value.flags.c_contiguous else 'strided'}, not {layout} C"
        return None
    kinds = {"int": (int, np.integer), "float": (float, int, np.floating, np.integer), "bool": (bool, np.bool_)}
    fits = isinstance(value, kinds[layout]) and (layout == "bool" or not isinstance(value, (bool, np.bool_)))
    return None if fits else f"{type(value).__name__}, not {layout}"


def export_name(function: Callable, label_bits: int | None = None) -> str:
    """The name a kernel is exported under: module and function, and the label width when it has one."""
    module = function.__module__.rsplit(".", 1)[-1].removesuffix("_kernels")
    return f"{module}__{function.__name__.lstrip('_')}" + ("" if label_bits is None else f"__{label_bits}")


def kernel(options: dict, label_arg: int | None = None) -> Callable[[Callable], Callable]:
    """Decorate a kernel that Python calls: the compiled export, or numba.njit(**options) of it.

    ``label_arg``: the position of the argument whose first field is the label array (a LabelTarget, a
    labelled layer); the kernel is then exported once per label width and each call takes the one its
    labels have. Compiled just in time, the kernel is listed in ENTRIES for the export table.
    """

    def decorate(function: Callable) -> Callable:
        compiled = compiled_module()
        if compiled is None:
            import numba

            dispatcher = numba.njit(**options)(function)
            ENTRIES.append(Entry(dispatcher, label_arg))
            return dispatcher
        if label_arg is None:
            return _compiled_export(export_name(function))
        by_width = {bits // 8: _compiled_export(export_name(function, bits)) for bits in LABEL_BITS}

        @functools.wraps(function)
        def by_label_width(*args):
            return by_width[args[label_arg][0].itemsize](*args)

        return by_label_width

    return decorate


def helper(options: dict, inline: bool = True) -> Callable[[Callable], Callable]:
    """Decorate a function that only kernels call: numba.njit of it (inlined into its callers unless
    ``inline`` is False) when the kernels compile just in time, the plain function otherwise."""

    def decorate(function: Callable) -> Callable:
        if compiled_module() is not None:
            return function
        import numba

        return numba.njit(**({"inline": "always"} if inline else {}), **options)(function)

    return decorate


def f64(array) -> np.ndarray:
    """The array as C-ordered float64 (no copy when it is one already): what the kernels take."""
    return np.ascontiguousarray(array, dtype=np.float64)


def f32(array) -> np.ndarray:
    """The array as C-ordered float32 (no copy when it is one already)."""
    return np.ascontiguousarray(array, dtype=np.float32)


def i64(array) -> np.ndarray:
    """The array as C-ordered int64 (no copy when it is one already)."""
    return np.ascontiguousarray(array, dtype=np.int64)
