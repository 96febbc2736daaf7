"""The ``heoslice`` group: exit statuses in every command's help (from errors.EXIT_CODES), shell completion."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from heoslice.cli import COMMANDS, EXIT_STATUSES
from heoslice.errors import EXIT_CODES


def listed_statuses(help_text: str) -> dict[int, str]:
    """The 'Exit status:' paragraph of a help text as {status: meaning}."""
    paragraph = help_text.split("Exit status:\n", 1)[1]
    rows = re.findall(r"^\s+(\d+)\s+(.+)$", paragraph.split("\n\n", 1)[0], flags=re.MULTILINE)
    return {int(code): " ".join(text.split()) for code, text in rows}


def test_every_command_declares_its_exit_statuses():
    """Each registered command has an entry in EXIT_STATUSES, and every status there has a meaning in EXIT_CODES."""
    assert set(EXIT_STATUSES) == set(COMMANDS)
    for statuses in EXIT_STATUSES.values():
        assert set(statuses) <= set(EXIT_CODES) and 0 in statuses


@pytest.mark.parametrize("command", list(COMMANDS))
def test_command_help_lists_its_exit_statuses_once(run_cli, command):
    """`heoslice CMD --help` ends with exactly its statuses and their meanings, once, however often asked."""
    run_cli(command, "--help")
    code, out, _ = run_cli(command, "--help")
    assert code == 0
    assert out.count("Exit status:") == 1
    assert listed_statuses(out) == {status: EXIT_CODES[status] for status in EXIT_STATUSES[command]}


def test_group_help_lists_every_exit_status_and_completion(run_cli):
    """`heoslice --help` lists every status heoslice uses and says how to enable completion."""
    code, out, _ = run_cli("--help")
    assert code == 0
    assert listed_statuses(out) == EXIT_CODES
    assert "_HEOSLICE_COMPLETE=bash_source heoslice" in out


def completion(**env: str) -> subprocess.CompletedProcess:
    """Run ``python -m heoslice`` as the shell's completion hook would, with these environment variables."""
    return subprocess.run([sys.executable, "-m", "heoslice"], env={**os.environ, **env}, capture_output=True,
                          text=True, timeout=60)


def test_bash_completion_script_is_produced():
    """`_HEOSLICE_COMPLETE=bash_source heoslice` prints a bash function registered for the heoslice command."""
    done = completion(_HEOSLICE_COMPLETE="bash_source")
    assert done.returncode == 0, done.stderr
    assert "_heoslice_completion()" in done.stdout
    assert "complete -o nosort -F _heoslice_completion heoslice" in done.stdout


@pytest.mark.parametrize(("words", "expected"), [("heoslice sl", "slice"), ("heoslice slice --int", "--into"),
                                                 ("heoslice --no-c", "--no-config")])
def test_bash_completion_completes_commands_and_options(words, expected):
    """The completion protocol offers sub-commands and their options (the lazily imported ones too)."""
    done = completion(_HEOSLICE_COMPLETE="bash_complete", COMP_WORDS=words, COMP_CWORD=str(len(words.split()) - 1))
    assert done.returncode == 0, done.stderr
    assert f"plain,{expected}" in done.stdout.splitlines()
