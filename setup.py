"""Builds the one compiled part of heoslice: the mesh's, the layers' and the grading's kernels, compiled
ahead of time from their numba sources (heoslice.kernel_exports) into the extension module
heoslice._compiled, for this machine's processor. Everything else is in pyproject.toml."""

import os
import shutil
import sys
import tempfile
import types
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


class BuildKernels(build_ext):
    """build_ext for the kernels' extension: numba.pycc compiles it (there is no C source to build)."""

    def build_extension(self, ext):
        os.environ["HEOSLICE_JIT"] = "1"  # the build compiles the numba functions, never an earlier extension
        # nor anything numba cached before: a kernel's cache entry holds the code of the kernels it calls and is
        # checked against its own module's file only, so one from before an edit to another module's kernel
        # would put that kernel's old code into the extension
        cache = tempfile.mkdtemp(prefix="heoslice-kernels-")
        os.environ["NUMBA_CACHE_DIR"] = cache
        try:
            self._compile(ext)
        finally:
            shutil.rmtree(cache, ignore_errors=True)

    def _compile(self, ext):
        """Compile the kernels into the extension's file (numba imported here, after its settings above)."""
        # the kernels' modules need numpy and numba only: their packages are entered without running their
        # __init__, which would load every stage (and every dependency) of heoslice
        source = Path(__file__).resolve().parent / "src" / "heoslice"
        for name, path in (("heoslice", source), ("heoslice.mesh", source / "mesh"),
                           ("heoslice.layers", source / "layers"), ("heoslice.material", source / "material"),
                           ("heoslice.grading", source / "grading")):
            package = types.ModuleType(name)
            package.__path__ = [str(path)]
            sys.modules[name] = package
        from heoslice.kernel_exports import compile_kernels

        target = Path(self.get_ext_fullpath(ext.name)).resolve()
        target.parent.mkdir(parents=True, exist_ok=True)
        compile_kernels(target.parent, target.name)


setup(ext_modules=[Extension("heoslice._compiled", sources=[])], cmdclass={"build_ext": BuildKernels})
