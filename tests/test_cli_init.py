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


# --- the statuses a command lists are the statuses its code can give ---------------------------------------------

#: Statuses every command can give whatever its code: success, a bug, a usage error (click), the signals.
ANY_COMMAND = {0, 1, 2, 129, 130, 141, 143}
#: (command, module) pairs whose raised statuses the command never gives, and why: what the reference below cannot
#: see (it reads whole modules, not the functions a command calls).
NEVER_REACHED = {
    ("slice", "heoslice.stack.read"): "reading a stack (VerifyError): slice only writes one",
    ("slice", "heoslice.stack.verify"): "verifying a stack: slice only writes one",
    ("slice", "heoslice.stack.tiff"): "decoding a layer (VerifyError): slice only encodes",
    ("slice", "heoslice.stack.manifest"): "checking a manifest read from disk: slice builds its own",
    ("export", "heoslice.locks"): "a slice's lock: export imports the slice command's module for its --dpi parser only",
    ("controller", "heoslice.printing.simulator.config"): "a bad option: the command says it as InputError (2)",
    ("controller", "heoslice.printing.ports"): "the host's port: the controller opens none",
    ("controller", "heoslice.printing.protocol"): "a bad frame from the host: the simulator logs it and goes on",
    **{(command, f"heoslice.stack.{module}"): "--scale's range check (cli.options -> pipeline.spec, which imports "
       "the stack package): info and color read no stack and write none"
       for command in ("info", "color") for module in ("write", "manifest", "read", "tiff", "verify", "packed")},
    ("slice", "heoslice.stack.packed"): "reading a stack's layers as packed bits: slice only writes one",
    ("verify", "heoslice.stack.write"): "writing a stack (OutputError): verify only reads one",
    **{(command, "heoslice.files"): "a volume's reader opens its input through files.open_regular (an input "
       "error, 2); the output rule's OutputError is for writers"
       for command in ("info", "verify")},
}


def _module_file(name: str):
    """The source file of heoslice module ``name``, or None when it is not one."""
    import importlib.util

    try:
        spec = importlib.util.find_spec(name) if name.startswith("heoslice") else None
    except ModuleNotFoundError:  # a name inside a module, not a module
        return None
    return spec.origin if spec is not None and spec.origin and spec.origin.endswith(".py") else None


def _imported(name: str) -> set[str]:
    """The heoslice modules module ``name`` imports (anywhere in it, lazily too): an imported function or class
    counts as the module that defines it, not the package that re-exports it."""
    import ast
    import importlib

    imported = set()
    for node in ast.walk(ast.parse(open(_module_file(name), encoding="utf-8").read())):
        if isinstance(node, ast.Import):
            imported |= {alias.name for alias in node.names if _module_file(alias.name)}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("heoslice"):
            for alias in node.names:
                if _module_file(f"{node.module}.{alias.name}"):
                    imported.add(f"{node.module}.{alias.name}")
                    continue
                where = getattr(getattr(importlib.import_module(node.module), alias.name, None), "__module__", None)
                imported.add(where if where and _module_file(where) else node.module)
    return imported


def _raised_statuses(name: str) -> set[int]:
    """The exit statuses module ``name`` raises: each heoslice error class it constructs (its exit_code), and each
    ``exit_code=EXIT_...`` it passes."""
    import ast

    from heoslice import errors

    found = set()
    for node in ast.walk(ast.parse(open(_module_file(name), encoding="utf-8").read())):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            error = getattr(errors, node.func.id, None)
            if isinstance(error, type) and issubclass(error, errors.HeosliceError):
                found.add(error.exit_code)
        if (isinstance(node, ast.keyword) and node.arg == "exit_code" and isinstance(node.value, ast.Name)
                and node.value.id.startswith("EXIT_")):
            found.add(getattr(errors, node.value.id))
    return found


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_commands_listed_statuses_are_exactly_those_its_code_can_give(command):
    """A reference read from the source: the statuses raised in every heoslice module a command's module reaches by
    its imports (each import followed to the module that defines the name), plus those any command gives, less the
    NEVER_REACHED modules (each with its reason), are the statuses its help lists, no more and no fewer."""
    reached, waiting = set(), [COMMANDS[command].split(":")[0]]
    while waiting:
        name = waiting.pop()
        if name not in reached:
            reached.add(name)
            waiting += _imported(name)
    by_module = {name: _raised_statuses(name) for name in reached if (command, name) not in NEVER_REACHED}
    possible = ANY_COMMAND.union(*by_module.values())
    if command == "controller":
        possible -= {129, 130, 143}  # it stops normally on a signal (exit 0), as its help says
    listed = set(EXIT_STATUSES[command])
    unlisted = {status: sorted(name for name, found in by_module.items() if status in found)
                for status in possible - listed}
    assert not unlisted, f"{command} can give {unlisted} (status: raised in) but its help does not list them"
    assert listed <= possible, f"{command}'s help lists {sorted(listed - possible)}, which nothing it runs gives"


@pytest.mark.parametrize("args", [["--help"], ["slice", "--help"], ["verify", "no_such_stack"]])
def test_a_reader_gone_away_ends_quietly_with_its_status(args):
    """Output to a pipe whose reader went away (`heoslice ... | head`) ends the command with 141 (128 + SIGPIPE, as a
    shell reports it) and nothing on stderr: not 'internal error' and exit 1 (a bug), nor a traceback at exit."""
    from heoslice.errors import EXIT_PIPE

    reader, writer = os.pipe()
    os.close(reader)  # gone before the command writes
    done = subprocess.run([sys.executable, "-m", "heoslice", *args], stdout=writer, stderr=subprocess.PIPE,
                          text=True, timeout=120)
    os.close(writer)
    if args[0] == "verify":  # its error line goes to stderr, and it writes nothing to stdout: its own status
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        return
    assert done.returncode == EXIT_PIPE and done.stderr == "", (done.returncode, done.stderr)


class _GoneReader:
    """A standard output whose reader went away: writes are kept, the flush fails as a closed pipe's does."""

    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        raise BrokenPipeError(32, "Broken pipe")

    def fileno(self) -> int:
        return os.open(os.devnull, os.O_WRONLY)


@pytest.mark.parametrize("status", [0, 4, 2])
def test_a_closed_pipe_at_exit_keeps_a_failed_commands_status(monkeypatch, status):
    """When the last flush finds the reader gone, a command that failed keeps its own status (its error line went
    to stderr); only one that succeeded ends with 141. A closed standard output (None) keeps the status too."""
    import heoslice.cli as cli_module
    from heoslice.errors import EXIT_PIPE

    def finished(argv):
        if status:
            raise SystemExit(status)

    monkeypatch.setattr(cli_module, "run", finished)
    monkeypatch.setattr(cli_module, "_silence_stdout", lambda: None)
    for stdout, expected in ((_GoneReader(), status or EXIT_PIPE), (None, status)):
        monkeypatch.setattr(sys, "stdout", stdout)
        if expected:
            with pytest.raises(SystemExit) as ended:
                cli_module.main([])
            assert ended.value.code == expected
        else:
            cli_module.main([])


@pytest.mark.parametrize("args, status", [(["--version"], 0), (["verify", "no_such_stack"], 2)])
def test_a_closed_standard_output_keeps_the_status(args, status):
    """Started with standard output closed (`>&-`, some daemons): the command's own status and at most its one
    error line, not a traceback and exit 1."""
    done = subprocess.run([sys.executable, "-m", "heoslice", *args], stderr=subprocess.PIPE, text=True, timeout=120,
                          preexec_fn=lambda: os.close(1))
    assert done.returncode == status and done.stderr.count("\n") == (1 if status else 0), done.stderr
