"""heoslice.jit: the kernels compiled ahead of time are the ones an installed heoslice runs, they make
the same stacks as numba's just-in-time compilation of the same sources, and they refuse (under the tests'
HEOSLICE_CHECK_KERNELS) arguments their compiled code would misread."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import modules_loaded_by_command

from heoslice import jit, procedural
from heoslice.jit import CHECK_VARIABLE, JIT_VARIABLE, compiled_module, layout_problem, source_digest

def write_mesh(mesh, path: Path) -> Path:
    path.write_bytes(mesh.export(file_type="ply", encoding="binary"))
    return path


GRADED = ["--grade", "linear", "--to", "0,255,0", "--nozzle", "0.6", "--channels", "--dpi", "150", "--layer", "1"]


def test_installed_heoslice_runs_the_kernels_compiled_from_these_sources():
    """The extension the install built is there, made from the kernels' present sources (its digest), and the
    kernel modules hand out its exports, not numba dispatchers: a broken or stale build fails here."""
    from heoslice.grading import field_kernels, search_kernels

    module = compiled_module()
    assert module is not None, "heoslice._compiled or _compiled_b missing or built from other sources: reinstall"
    assert module.source_digest() == source_digest()
    assert "numba" not in type(search_kernels._candidates).__module__
    assert field_kernels._expand_planes.__wrapped__.__name__ == "_expand_planes"  # chosen by label width


def test_a_graded_slice_with_droplet_masks_loads_no_numba(tmp_path):
    """A graded `heoslice slice --channels` (a fresh process) never imports numba or LLVM: with the compiled
    kernels the graded path's fixed cost is the one-material path's plus the kernels (benchmarks/README.md)."""
    model = write_mesh(procedural.holes_and_islands((20.0, 12.0, 4.0), 16), tmp_path / "holes.ply")
    args = ["slice", str(model), "-o", str(tmp_path / "out"), *GRADED]
    assert modules_loaded_by_command(args, ("numba", "llvmlite")) == []


def _slice(model: Path, out: Path, environment: dict) -> dict[str, bytes]:
    done = subprocess.run([sys.executable, "-m", "heoslice", "--no-config", "slice", str(model), "-o", str(out),
                           "-j", "1", *GRADED], capture_output=True, text=True, timeout=600,
                          env={**os.environ, **environment})
    assert done.returncode == 0, done.stderr
    return {path.name: path.read_bytes() for path in sorted(out.iterdir())}


@pytest.mark.slow  # among the slowest (README "Development"): numba compiles the graded path's kernels
def test_compiled_and_just_in_time_kernels_make_the_same_stack(tmp_path):
    """The same graded job (holes and islands: several ring sets, nested families, droplet masks) sliced with
    the compiled kernels and with numba compiling the same sources just in time: every file byte for byte."""
    model = write_mesh(procedural.holes_and_islands((30.0, 20.0, 4.0), 24), tmp_path / "holes.ply")
    compiled = _slice(model, tmp_path / "compiled", {JIT_VARIABLE: "0"})
    just_in_time = _slice(model, tmp_path / "jit", {JIT_VARIABLE: "1"})
    assert len(compiled) > 10 and compiled.keys() == just_in_time.keys()
    assert [name for name in compiled if compiled[name] != just_in_time[name]] == []


def test_a_compiled_kernel_refuses_arrays_of_another_type_or_layout():
    """Under HEOSLICE_CHECK_KERNELS a compiled kernel raises TypeError, naming the argument, for a strided
    array or another dtype (its compiled code would read them as C-ordered float64)."""
    from heoslice.grading.search_kernels import _chunk_capsules

    assert os.environ.get(CHECK_VARIABLE) == "1" and compiled_module() is not None
    x = np.arange(8.0)
    assert _chunk_capsules(x, x, x + 1, x + 1).shape[0] >= 1
    with pytest.raises(TypeError, match="chunk_capsules: argument 0: float64 1d strided"):
        _chunk_capsules(np.arange(16.0)[::2], x, x + 1, x + 1)
    with pytest.raises(TypeError, match="argument 2: float32 1d C, not float64 1d C"):
        _chunk_capsules(x, x, (x + 1).astype(np.float32), x + 1)


@pytest.mark.parametrize(("value", "layout", "problem"), [
    (np.zeros((2, 3)), "float64 2d", None),
    (np.zeros((2, 3)).T, "float64 2d", "strided"),
    (np.zeros(3, np.int16), "int16 1d", None),
    (np.zeros(3, np.int16), "int32 1d", "not int32 1d"),
    ([1.0], "float64 1d", "not an array"),
    (3, "int", None),
    (np.int64(3), "int", None),
    (True, "int", "not int"),
    (3, "float", None),
    (2.5, "int", "not int"),
    (np.True_, "bool", None),
    ((np.zeros(2), 1, 2.0), ["float64 1d", "int", "float"], None),
    ((np.zeros(2), 1), ["float64 1d", "int", "float"], "not a tuple of 3"),
    ((np.zeros(2, np.float32), 1), ["float64 1d", "int"], "item 0: float32"),
])
def test_layout_problem_names_what_differs(value, layout, problem):
    """layout_problem is None where the value is what the export takes, else a phrase with the difference."""
    found = layout_problem(value, layout)
    assert (found is None) if problem is None else (problem in found)


def test_the_compiled_kernels_are_set_aside_when_stale_or_asked_to_be(monkeypatch):
    """An extension built from other sources (its digest differs) is not used, nor any with HEOSLICE_JIT=1:
    the kernels then compile just in time from the sources as they are."""
    built = compiled_module()
    assert built is not None
    try:
        compiled_module.cache_clear()
        monkeypatch.setattr(jit, "source_digest", lambda: built.source_digest() + 1)
        assert compiled_module() is None
        monkeypatch.undo()
        compiled_module.cache_clear()
        monkeypatch.setenv(JIT_VARIABLE, "1")
        assert compiled_module() is None
        monkeypatch.setenv(JIT_VARIABLE, "0")
        compiled_module.cache_clear()
        assert compiled_module() == built
    finally:
        compiled_module.cache_clear()


def test_the_digest_covers_every_kernel_source(tmp_path, monkeypatch):
    """source_digest reads jit.py, kernel_exports.py and every stage's *_kernels.py: a change to any of them
    changes it."""
    package = Path(jit.__file__).parent
    names = ["jit.py", "kernel_exports.py", *sorted(p.relative_to(package).as_posix()
                                                    for p in package.glob("*/*_kernels.py"))]
    assert "layers/rasterising_kernels.py" in names and "grading/lattice_kernels.py" in names
    assert [path.relative_to(package).as_posix() for path in jit.kernel_sources()] == names
    for name in names:
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_bytes((package / name).read_bytes())
    monkeypatch.setattr(jit, "__file__", str(tmp_path / "jit.py"))
    original = source_digest()
    assert original == compiled_module().source_digest()
    for name in names:
        path = tmp_path / name
        kept = path.read_bytes()
        path.write_bytes(kept + b"\n")
        assert source_digest() != original, name
        path.write_bytes(kept)
    assert source_digest() == original
