"""The package reads as the pipeline: no module imports from a later stage (read from the source with ast)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import heoslice

SOURCE = Path(heoslice.__file__).resolve().parent
#: The stages in pipeline order; a module may import its own stage or an earlier one, never a later one. The
#: kernels' build comes after the last stage with compiled kernels (export's Voxel Print run coder), as it imports them all.
STAGES = ("base", "mesh", "material", "layers", "grading", "volume", "stack", "pipeline", "preview", "export", "build",
          "printing", "cli")
#: The stage of each first name under heoslice (a package, or a base module that every stage may use).
STAGE_OF = {
    "__init__": "base", "errors": "base", "files": "base", "jit": "base", "lazy": "base", "locks": "base", "signals": "base",
    "pngfile": "base", "deflate": "base",
    "mesh": "mesh", "procedural": "mesh",
    "material": "material", "layers": "layers", "grading": "grading", "volume": "volume", "kernel_exports": "build", "stack": "stack",
    "pipeline": "pipeline",
    "preview": "preview", "export": "export", "printing": "printing",
    "cli": "cli", "__main__": "cli",
}


def modules() -> list[tuple[str, Path]]:
    """Every module of the package: (dotted name below heoslice, path)."""
    found = []
    for path in sorted(SOURCE.rglob("*.py")):
        parts = path.relative_to(SOURCE).with_suffix("").parts
        found.append((".".join(parts), path))
    return found


def imported(path: Path, name: str) -> list[tuple[int, str]]:
    """(line, dotted name below heoslice) of every heoslice module or name imported anywhere in the module
    at ``path`` (``name`` its own dotted name), function-local imports included."""
    package = name.split(".")[:-1]
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ["heoslice", *package[: len(package) - node.level + 1]]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            names += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
    return [(line, full.split(".", 1)[1]) for line, full in names if full.startswith("heoslice.")]


def stage(dotted: str) -> str | None:
    """The stage of a dotted name below heoslice (None for a name of heoslice/__init__, e.g. __version__)."""
    first = dotted.split(".")[0]
    if first in STAGE_OF:
        return STAGE_OF[first]
    return "base" if "." not in dotted and not (SOURCE / f"{first}.py").exists() else None


@pytest.mark.parametrize("name, path", modules(), ids=[name for name, _ in modules()])
def test_no_module_imports_from_a_later_stage(name, path):
    """Every import of a heoslice module names its own stage or an earlier one (base imports no stage)."""
    own = STAGE_OF.get(name.split(".")[0])
    assert own is not None, f"{name}: no stage for it in STAGE_OF (add it in pipeline order)"
    upward = [f"line {line}: {target} ({stage(target)})" for line, target in imported(path, name)
              if stage(target) is not None and STAGES.index(stage(target)) > STAGES.index(own)]
    assert not upward, f"{name} ({own}) imports from a later stage: {'; '.join(upward)}"


def test_the_check_sees_an_upward_import(tmp_path):
    """The reader finds an upward import in a function body and a relative one (the test can fail)."""
    module = tmp_path / "slicing.py"
    module.write_text("def f():\n    from heoslice.pipeline import SliceSpec\nfrom .stack import x\n")
    targets = [target for _, target in imported(module, "layers.slicing")]
    assert sorted(targets) == ["layers.stack.x", "pipeline.SliceSpec"]
    assert STAGES.index(stage("pipeline.SliceSpec")) > STAGES.index("layers")
