"""Shared fixtures: the third-party mesh folder (skipped when absent) and a CLI runner. Every compiled
kernel checks its arguments in the tests (and in the commands they run): the compiled code would misread
an array of another type or layout rather than refuse it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("HEOSLICE_CHECK_KERNELS", "1")  # before any heoslice kernel module is imported

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """The third-party meshes: $HEOSLICE_SHARED_DATA, else ../shared/data beside the repo."""
    return Path(os.environ.get("HEOSLICE_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of the shared mesh folder; skips the test when it is absent."""
    folder = shared_data_dir()
    if not folder.is_dir():
        pytest.skip(f"shared meshes not found at {folder} (set HEOSLICE_SHARED_DATA)")
    return folder


def shared_meshes(subfolder: str | None = None, pattern: str = "*.ply") -> list[Path]:
    """Mesh files of the shared folder (for parametrize); empty when the folder is absent."""
    folder = shared_data_dir()
    if subfolder:
        folder = folder / subfolder
    if not folder.is_dir():
        return []
    return sorted(folder.rglob(pattern))


@pytest.fixture
def run_cli():
    """Run ``heoslice`` in-process: returns (exit code, stdout, stderr)."""
    from heoslice.cli import main

    def run(*args: str) -> tuple[int, str, str]:
        import contextlib
        import io

        out, err = io.StringIO(), io.StringIO()
        code = 0
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main([str(a) for a in args])
            except SystemExit as done:
                code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
        return code, out.getvalue(), err.getvalue()

    return run


@pytest.fixture(scope="module")
def lattice_fit_for_every_family():
    """Every family is fitted on the lattice however small (most test shapes are below
    field.DIRECT_PIXELS), for the modules of grading tests that ask for it with
    ``pytestmark = pytest.mark.usefixtures("lattice_fit_for_every_family")``; their tests of the exact
    per-pixel path ask for that path themselves."""
    from heoslice.grading import field as field_module

    saved = field_module.DIRECT_PIXELS
    field_module.DIRECT_PIXELS = 0
    yield
    field_module.DIRECT_PIXELS = saved


@pytest.fixture(autouse=True)
def _no_user_defaults_file(monkeypatch, tmp_path_factory):
    """No test reads the developer's own ~/.config/heoslice/heoslice.toml (defaults files, cli/defaults.py)."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path_factory.getbasetemp() / "no-user-config"))
