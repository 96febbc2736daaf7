"""Packages whose public names are loaded on first use (PEP 562), from a table of submodule -> its names."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable


def lazy_exports(package: str, modules: dict[str, tuple[str, ...]]
                 ) -> tuple[list[str], Callable[[str], object], Callable[[], list[str]]]:
    """``__all__``, the module ``__getattr__`` and ``__dir__`` of ``package`` (its ``__name__``) whose public
    names are those of ``modules`` (submodule -> the names it defines): a name's submodule is imported when
    the name is first asked for, not when the package is, and then kept in the package, so that later uses (a
    ``from package import name`` in a function run once a layer) find it without this hook; except a name that is
    also a submodule's, which the package attribute keeps for the submodule (``import package.name`` binds it)."""
    exports = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        if name not in modules:
            setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted([*vars(sys.modules[package]), *exports])

    return sorted(exports), __getattr__, __dir__
