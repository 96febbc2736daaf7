"""The ``heoslice`` command: a thin shell that parses options, calls the library, reports.

Each sub-command lives in its own module here; this one holds the group and the
error policy: a :class:`~heoslice.errors.HeosliceError` becomes one line on stderr
and its exit status; any other exception is a bug, shown as one line unless
``--debug`` asks for the traceback.
"""

from __future__ import annotations

import gc
import importlib
import os
import sys
import traceback

import click

from heoslice import __version__
from heoslice.errors import EXIT_BUG, EXIT_INTERRUPTED, HeosliceError

EPILOG = """\b
Examples:
  heoslice info vase.ply
  heoslice color vase.ply --func linear
  heoslice slice vase.ply --layer 0.1 --dpi 600
  heoslice verify vase_stack/
  heoslice print vase_stack/ --port /dev/ttyUSB0
"""


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


class LazyGroup(click.Group):
    """A click group whose sub-commands are imported on first use (click's documented pattern)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module, attribute = COMMANDS[name].split(":")
        return getattr(importlib.import_module(module), attribute)


@click.group(cls=LazyGroup, epilog=EPILOG, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="heoslice")
@click.option("--debug", is_flag=True, help="Show full tracebacks (for bug reports).")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Slice coloured meshes into graded multi-material layer images and print them."""
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: run the group, map errors to one line and an exit status."""
    args = sys.argv[1:] if argv is None else argv
    if argv is None:
        # this process's own command: heoslice makes no BLAS call worth threads (its workers are processes),
        # and OpenBLAS's thread pools, started when numpy and scipy load it, only spin (~0.2 s of CPU a run)
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    debug = "--debug" in args
    try:
        cli.main(args=args, prog_name="heoslice", standalone_mode=False)
        if argv is None:
            # this process's own command is done and it ends now: its objects need no collection pass at exit,
            # which costs ~0.2 s once slicing has loaded its compiled kernels
            gc.freeze()
    except click.exceptions.Exit as done:
        sys.exit(done.exit_code)
    except click.ClickException as err:
        where = err.ctx.command_path if isinstance(err, click.UsageError) and err.ctx else "heoslice"
        hint = f" (see '{where} --help')" if isinstance(err, click.UsageError) else ""
        click.echo(f"heoslice: error: {' '.join(err.format_message().split())}{hint}", err=True)
        sys.exit(err.exit_code)
    except click.exceptions.Abort:
        click.echo("heoslice: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except KeyboardInterrupt:
        click.echo("heoslice: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except HeosliceError as err:
        if debug:
            traceback.print_exc()
        click.echo(f"heoslice: error: {err}", err=True)
        sys.exit(err.exit_code)
    except Exception as err:  # noqa: BLE001 - the last line of defence for users
        if debug:
            traceback.print_exc()
        click.echo(
            f"heoslice: internal error: {type(err).__name__}: {err} "
            "(rerun with --debug and report the traceback)",
            err=True,
        )
        sys.exit(EXIT_BUG)
