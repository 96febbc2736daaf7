"""The ``heoslice`` command: a thin shell that parses options, calls the library, reports.

Each sub-command lives in its own module here; this one holds the group and the
error policy: a :class:`~heoslice.errors.HeosliceError` becomes one line on stderr
and its exit status; any other exception is a bug, shown as one line unless
``--debug`` asks for the traceback.
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

import click

from heoslice import __version__
from heoslice.cli.common import error_line, exit_status_epilog
from heoslice.errors import (
    EXIT_BUG,
    EXIT_BUSY,
    EXIT_CODES,
    EXIT_CONTROLLER,
    EXIT_FINISHED,
    EXIT_HANGUP,
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    EXIT_LINK_DEAD,
    EXIT_OK,
    EXIT_OUTPUT,
    EXIT_PIPE,
    EXIT_PORT,
    EXIT_PROTOCOL,
    EXIT_RESET,
    EXIT_RETRIES,
    EXIT_STACK_BUSY,
    EXIT_STACK_CHANGED,
    EXIT_TERMINATED,
    EXIT_UNFINISHED,
    EXIT_VERIFY,
)
from heoslice.pipeline import parallel
from heoslice.signals import interrupt_on_terminating_signals

EPILOG = """\b
Examples:
  heoslice info vase.ply
  heoslice color vase.ply --func linear
  heoslice slice vase.ply --layer 0.1 --dpi 600
  heoslice verify vase_stack/
  heoslice print vase_stack/ --port /dev/ttyUSB0
\b
Option defaults are read from ./heoslice.toml and ~/.config/heoslice/heoslice.toml
(a table per command, e.g. [slice] dpi = "600"); options given here override them.
Shell completion (bash): eval "$(_HEOSLICE_COMPLETE=bash_source heoslice)"
"""


#: The environment variable with which a shell asks for completions (click's convention for "heoslice").
COMPLETION_VARIABLE = "_HEOSLICE_COMPLETE"

#: Sub-command name -> "module:attribute"; imported only when that command runs, so
#: `heoslice slice` does not pay for the printer link and `--help` stays quick.
COMMANDS = {
    "info": "heoslice.cli.info:info",
    "color": "heoslice.cli.color:color",
    "slice": "heoslice.cli.slice:slice_cmd",
    "preview": "heoslice.cli.preview:preview",
    "verify": "heoslice.cli.verify:verify",
    "export": "heoslice.cli.export:export",
    "print": "heoslice.cli.print:print_cmd",
    "controller": "heoslice.cli.controller:controller",
}


_COMMON_EXITS = (EXIT_OK, EXIT_BUG, EXIT_INPUT, EXIT_HANGUP, EXIT_INTERRUPTED, EXIT_PIPE, EXIT_TERMINATED)
_PRINTER_EXITS = (EXIT_PORT, EXIT_LINK_DEAD, EXIT_PROTOCOL, EXIT_RETRIES, EXIT_RESET, EXIT_CONTROLLER, EXIT_BUSY,
                  EXIT_UNFINISHED, EXIT_STACK_BUSY, EXIT_STACK_CHANGED, EXIT_FINISHED)

#: Sub-command name -> the exit statuses it can end with, listed in its --help (meanings from errors.EXIT_CODES).
EXIT_STATUSES = {
    "info": _COMMON_EXITS,
    "color": (*_COMMON_EXITS, EXIT_OUTPUT),
    "slice": (*_COMMON_EXITS, EXIT_OUTPUT, EXIT_STACK_BUSY),  # busy: a print or another slice holds the stack
    "preview": (*_COMMON_EXITS, EXIT_OUTPUT, EXIT_VERIFY),
    "verify": (*_COMMON_EXITS, EXIT_VERIFY),
    "print": (*_COMMON_EXITS, EXIT_OUTPUT, EXIT_VERIFY, *_PRINTER_EXITS),
    "export": (*_COMMON_EXITS, EXIT_OUTPUT, EXIT_VERIFY),
    "controller": (EXIT_OK, EXIT_BUG, EXIT_INPUT, EXIT_PIPE),  # a signal stops it normally
}


class LazyGroup(click.Group):
    """A click group whose sub-commands are imported on first use (click's documented pattern).

    Each command's help gets the 'Exit status:' paragraph of its EXIT_STATUSES entry.
    """

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module, attribute = COMMANDS[name].split(":")
        command = getattr(importlib.import_module(module), attribute)
        epilog = exit_status_epilog(EXIT_STATUSES[name])
        if epilog not in (command.epilog or ""):
            command.epilog = f"{command.epilog or ''}\n{epilog}".lstrip("\n")
        return command


@click.group(cls=LazyGroup, epilog=EPILOG + "\n" + exit_status_epilog(tuple(EXIT_CODES)),
             context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="heoslice")
@click.option("--debug", is_flag=True, help="Show full tracebacks (for bug reports).")
@click.option("--config", "config_file", type=click.Path(path_type=Path, exists=True, dir_okay=False),
              default=None, metavar="FILE",
              help="Read option defaults from FILE only [default: ~/.config/heoslice/heoslice.toml, "
                   "then ./heoslice.toml].")
@click.option("--no-config", is_flag=True, help="Read no defaults file.")
@click.pass_context
def cli(ctx: click.Context, debug: bool, config_file: Path | None, no_config: bool) -> None:
    """Slice coloured meshes into graded multi-material layer images and print them."""
    from heoslice.cli.defaults import load_defaults

    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    if config_file is not None and no_config:
        raise click.UsageError("give --config FILE or --no-config, not both")
    if ctx.invoked_subcommand is not None:
        defaults = load_defaults(config_file, no_config, ctx.command, ctx, ctx.invoked_subcommand)
        ctx.obj["defaults"] = defaults
        ctx.default_map = {ctx.invoked_subcommand: defaults.values} if defaults.values else None


def _interrupted_line(interrupt: BaseException | None) -> str:
    """The one line an interruption ends with: 'heoslice: interrupted', then what the work left behind (the
    interruption's PEP 678 notes, e.g. an incomplete stack and the command that replaces it)."""
    notes = getattr(interrupt, "__notes__", None) or ()
    return ": ".join(["heoslice: interrupted", *(" ".join(str(note).split()) for note in notes)])


def _silence_stdout() -> None:
    """Point standard output at /dev/null: its reader went away, and later flushes (at exit) would fail again."""
    sink = os.open(os.devnull, os.O_WRONLY)
    os.dup2(sink, sys.stdout.fileno())
    os.close(sink)


def _end_on_closed_pipe() -> None:
    """Exit EXIT_PIPE, quietly: standard output's reader went away while the command wrote."""
    _silence_stdout()
    sys.exit(EXIT_PIPE)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: :func:`run`, and standard output flushed while an exit status can still be set:
    a reader that went away ends a command that succeeded with EXIT_PIPE (a failed one keeps its status), not with
    a traceback at the interpreter's exit. A closed standard output (``>&-``: no sys.stdout) is left alone."""
    status = 0
    try:
        run(argv)
    except SystemExit as done:
        status = done.code
        raise
    finally:
        if sys.stdout is not None:
            try:
                sys.stdout.flush()
            except BrokenPipeError:
                _silence_stdout()
                if not status:
                    sys.exit(EXIT_PIPE)


def run(argv: list[str] | None = None) -> None:
    """Run the group, map errors to one line and an exit status."""
    args = sys.argv[1:] if argv is None else argv
    if argv is None:
        parallel.command_environment()
    debug = "--debug" in args
    state: dict = {}
    interrupt_on_terminating_signals()
    try:
        if COMPLETION_VARIABLE in os.environ:  # click's main answers shell completion
            cli.main(args=args, prog_name="heoslice", standalone_mode=False, obj=state)
        else:  # not cli.main: it echoes a blank line on Ctrl-C before our one line
            with cli.make_context("heoslice", list(args), obj=state) as ctx:
                cli.invoke(ctx)
        if argv is None:
            parallel.skip_exit_collection()
    except click.exceptions.Exit as done:
        sys.exit(done.exit_code)
    except click.ClickException as err:
        where = err.ctx.command_path if isinstance(err, click.UsageError) and err.ctx else "heoslice"
        hint = f" (see '{where} --help')" if isinstance(err, click.UsageError) else ""
        click.echo(f"heoslice: error: {' '.join(err.format_message().split())}{hint}", err=True)
        sys.exit(err.exit_code)
    except click.exceptions.Abort as abort:
        interrupt = abort.__cause__ or abort.__context__
        click.echo(_interrupted_line(interrupt), err=True)
        sys.exit(getattr(interrupt, "exit_code", EXIT_INTERRUPTED))
    except KeyboardInterrupt as interrupt:
        click.echo(_interrupted_line(interrupt), err=True)
        sys.exit(getattr(interrupt, "exit_code", EXIT_INTERRUPTED))
    except BrokenPipeError:  # the reader went away (`| head`): end quietly, as a shell reports a closed pipe's writer
        _end_on_closed_pipe()
    except Exception as err:  # noqa: BLE001 - the last line of defence for users; a HeosliceError is theirs
        line, code = error_line(err, debug)
        where = state["defaults"].origin(str(err), args) if "defaults" in state and code != EXIT_BUG else None
        click.echo(line + (f" (set in {where})" if where else ""), err=True)
        sys.exit(code)
