"""Builds the one compiled part of heoslice: the mesh's, the layers', the grading's and the export's kernels, compiled
ahead of time from their numba sources (heoslice.kernel_exports) into the extension modules
heoslice._compiled and heoslice._compiled_b (a share each, compiled side by side), for this machine's processor. Everything else is in pyproject.toml.

The compiled extension is kept in a cache (``$HEOSLICE_KERNEL_CACHE``, else ``$XDG_CACHE_HOME/heoslice/kernels``
or ``~/.cache/heoslice/kernels``; ``HEOSLICE_KERNEL_CACHE=off`` keeps none) under a key of everything it is made
from: the kernels' sources, this file, Python, numpy, numba and llvmlite, the platform and the processor. Installing
the same sources again (the README's second command, a reinstall into a fresh environment) copies it instead of
compiling the kernels again."""

import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import types
from pathlib import Path

#: The environment variable naming the compiled kernels' cache directory, or "off" for none.
CACHE_VARIABLE = "HEOSLICE_KERNEL_CACHE"
#: The extension modules the kernels are compiled into, a share each (heoslice.kernel_exports.module_part).
MODULES = ("heoslice._compiled", "heoslice._compiled_b")
#: The argument that makes this file compile one module's kernels (the build runs it once per module, in parallel).
PART_FLAG = "--heoslice-compile-kernels"

from setuptools import Extension, setup  # noqa: E402
from setuptools.command.build_ext import build_ext  # noqa: E402


class BuildKernels(build_ext):
    """build_ext for the kernels' extension modules: numba.pycc compiles them (there is no C source to build),
    one process per module, side by side on as many cores as this process may use; a module the cache holds for
    these very inputs is copied instead."""

    def build_extensions(self):
        os.environ["HEOSLICE_JIT"] = "1"  # the build compiles the numba functions, never an earlier extension
        _enter_kernel_packages()
        compiles = []
        for part, ext in enumerate(self.extensions):
            target = Path(self.get_ext_fullpath(ext.name)).resolve()
            target.parent.mkdir(parents=True, exist_ok=True)
            cached = _cache_path(target.name)
            if cached is not None and cached.is_file():
                print(f"heoslice: {ext.name} compiled before from these sources, copied from {cached}")
                shutil.copyfile(cached, target)
            else:
                compiles.append((part, target, cached))
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        for first in range(0, len(compiles), max(1, cores)):
            batch = compiles[first:first + max(1, cores)]
            running = [(subprocess.Popen([sys.executable, str(Path(__file__).resolve()), PART_FLAG, str(part),
                                          str(target)]), target) for part, target, _ in batch]
            failed = [str(target) for process, target in running if process.wait() != 0]
            if failed:
                raise RuntimeError(f"compiling the kernels failed: {', '.join(failed)}")
        for _, target, cached in compiles:
            if cached is not None:
                _keep(target, cached)


def _compile_part(part: int, target: Path) -> None:
    """Compile the kernels of extension module ``part`` into ``target`` (this file run with PART_FLAG).

    numba is imported here, after its settings: never an earlier extension nor anything numba cached before (a
    kernel's cache entry holds the code of the kernels it calls and is checked against its own module's file
    only, so one from before an edit to another module's kernel would put that kernel's old code in)."""
    os.environ["HEOSLICE_JIT"] = "1"
    cache = tempfile.mkdtemp(prefix="heoslice-kernels-")
    os.environ["NUMBA_CACHE_DIR"] = cache
    try:
        _enter_kernel_packages()
        from heoslice.kernel_exports import compile_kernels

        compile_kernels(target.parent, target.name, part)
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def _enter_kernel_packages() -> None:
    """Make heoslice's packages importable without running their __init__: the kernels' modules need numpy and
    numba only, and the packages' __init__ would load every stage (and every dependency) of heoslice."""
    source = Path(__file__).resolve().parent / "src" / "heoslice"
    for name, path in (("heoslice", source), ("heoslice.mesh", source / "mesh"),
                       ("heoslice.layers", source / "layers"), ("heoslice.material", source / "material"),
                       ("heoslice.grading", source / "grading"), ("heoslice.export", source / "export"),
                       ("heoslice.stack", source / "stack")):
        package = types.ModuleType(name)
        package.__path__ = [str(path)]
        sys.modules[name] = package


def _cache_path(filename: str) -> Path | None:
    """Where the extension compiled from these very inputs is kept (``filename`` under a digest of them), or None
    when HEOSLICE_KERNEL_CACHE is "off"."""
    setting = os.environ.get(CACHE_VARIABLE, "")
    if setting.lower() == "off":
        return None
    import llvmlite
    import llvmlite.binding as llvm
    import numba
    import numpy

    from heoslice.jit import source_digest

    inputs = [str(source_digest()), hashlib.sha256(Path(__file__).read_bytes()).hexdigest(), sys.version,
              platform.platform(), numpy.__version__, numba.__version__, llvmlite.__version__,
              llvm.get_host_cpu_name(), llvm.get_host_cpu_features().flatten()]
    key = hashlib.sha256("\0".join(inputs).encode()).hexdigest()[:32]
    base = (Path(setting) if setting else
            Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "heoslice" / "kernels")
    return base / key / filename


def _keep(built: Path, cached: Path) -> None:
    """Copy the compiled extension into the cache, atomically (a file there is always whole); a cache that cannot
    be written is skipped with a line (the install itself succeeded)."""
    try:
        cached.parent.mkdir(parents=True, exist_ok=True)
        partial = cached.with_name(f".{cached.name}.{os.getpid()}")
        shutil.copyfile(built, partial)
        os.replace(partial, cached)
    except OSError as err:
        print(f"heoslice: the compiled kernels were not cached ({err})")


if __name__ == "__main__" and sys.argv[1:2] == [PART_FLAG]:
    _compile_part(int(sys.argv[2]), Path(sys.argv[3]))
else:
    setup(ext_modules=[Extension(name, sources=[]) for name in MODULES], cmdclass={"build_ext": BuildKernels})
