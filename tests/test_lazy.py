"""heoslice.lazy: a package's public names load their submodule on first use, and are kept in the package after it."""

from __future__ import annotations

import sys

import pytest


@pytest.fixture()
def lazy_package(tmp_path, monkeypatch):
    """A package ``lazyprobe`` whose public names ``answer`` and ``part`` live in its submodule ``part``."""
    package = tmp_path / "lazyprobe"
    package.mkdir()
    (package / "__init__.py").write_text(
        "from heoslice.lazy import lazy_exports\n"
        "__all__, __getattr__, __dir__ = lazy_exports(__name__, {'part': ('answer', 'part')})\n")
    (package / "part.py").write_text("answer = object()\npart = object()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    for name in ("lazyprobe", "lazyprobe.part"):
        sys.modules.pop(name, None)


def test_a_name_loads_its_submodule_on_first_use_and_is_then_kept_in_the_package(lazy_package):
    """Importing the package loads no submodule; the first use of a name loads its submodule and stores the name in
    the package's namespace (a later use, or ``from package import name`` once a layer, skips the hook)."""
    import lazyprobe

    assert "lazyprobe.part" not in sys.modules
    assert "answer" not in vars(lazyprobe)
    first = lazyprobe.answer
    assert first is sys.modules["lazyprobe.part"].answer
    assert vars(lazyprobe)["answer"] is first
    from lazyprobe import answer

    assert answer is first


def test_an_unknown_name_is_an_attribute_error_and_dir_lists_the_exports(lazy_package):
    """A name no submodule exports raises AttributeError naming the package; dir() shows the exports unloaded."""
    import lazyprobe

    with pytest.raises(AttributeError, match="lazyprobe"):
        lazyprobe.missing  # noqa: B018
    assert "answer" in dir(lazyprobe)
    assert lazyprobe.__all__ == ["answer", "part"]


def test_a_name_that_is_also_a_submodule_leaves_the_package_attribute_to_the_submodule(lazy_package):
    """Reading ``part`` (a name of submodule ``part``) before the submodule is imported gives the name, and does not
    store it over the submodule: ``import lazyprobe.part`` still gives the module."""
    import lazyprobe

    value = lazyprobe.part
    assert value is sys.modules["lazyprobe.part"].part
    import lazyprobe.part as submodule

    assert submodule is sys.modules["lazyprobe.part"]
