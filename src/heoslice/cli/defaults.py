"""Defaults files: ``heoslice.toml`` with a table of option defaults per command, given to click as ``default_map``.

Read, lowest precedence first: the user's file (``$XDG_CONFIG_HOME/heoslice/heoslice.toml``,
``~/.config`` when unset), then ``./heoslice.toml`` in the working directory, key by key;
``heoslice --config FILE`` reads only FILE and ``--no-config`` none. Options given on
the command line override every file. Keys are a command's long option names
(``layer = 0.1``, ``from-layer`` or ``from_layer``); values are checked as the command
line would check them, and anything wrong is one error naming the file.
"""

from __future__ import annotations

import difflib
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import click

from heoslice.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

FILE_NAME = "heoslice.toml"
MAX_BYTES = 1 << 20  # a defaults file is a few lines; anything larger is not one

#: Options that act on one run only and so cannot be defaults: where a run writes (a file in a downloaded
#: project folder must not redirect outputs), overwriting, where a print resumes.
PER_RUN_OPTIONS = frozenset({"output", "into", "log", "force", "from-layer", "help"})


@dataclass(frozen=True, slots=True)
class DefaultsFile:
    """One parsed defaults file: its path (as shown in messages) and its tables, command -> {key: TOML value}."""

    path: Path
    tables: dict[str, dict[str, object]]


def user_file() -> Path:
    """``$XDG_CONFIG_HOME/heoslice/heoslice.toml``; ``~/.config`` when the variable is unset or not absolute."""
    base = os.environ.get("XDG_CONFIG_HOME", "")
    root = Path(base) if base and Path(base).is_absolute() else Path.home() / ".config"
    return root / "heoslice" / FILE_NAME


def find_files(explicit: Path | None, disabled: bool) -> list[Path]:
    """The defaults files to read, lowest precedence first."""
    if disabled:
        return []
    if explicit is not None:
        return [explicit]
    found: list[Path] = []
    for candidate in (user_file(), Path(FILE_NAME)):
        if candidate.exists() and not any(_same_file(candidate, known) for known in found):
            found.append(candidate)
    return found


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.samefile(b)
    except OSError:
        return False


def read_file(path: Path, commands: list[str] | tuple[str, ...]) -> DefaultsFile:
    """Parse one defaults file: TOML whose top level holds only tables named after commands."""
    if not path.is_file():
        raise InputError(f"{path}: not a regular file (a defaults file is TOML)")
    try:
        with path.open("rb") as handle:
            data = handle.read(MAX_BYTES + 1)
    except OSError as err:
        raise InputError(f"{path}: cannot be read ({err.strerror or err})") from None
    if len(data) > MAX_BYTES:
        raise InputError(f"{path}: larger than {MAX_BYTES // 1024} KB; not a defaults file")
    try:
        document = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text (a defaults file is TOML)") from None
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"{path}: not valid TOML ({err})") from None
    except RecursionError:
        raise InputError(f"{path}: arrays or tables nested too deeply; not a defaults file "
                         "(heoslice --no-config ignores it)") from None
    for name, table in document.items():
        if not isinstance(table, dict):
            raise InputError(f"{path}: {name} = ... is outside a table; put it under its command, e.g. [slice]")
        if name not in commands:
            raise InputError(f"{path}: [{name}] is not a heoslice command (tables: {', '.join(commands)})")
    return DefaultsFile(path=path, tables=document)


@dataclass(frozen=True, slots=True)
class Defaults:
    """What the defaults files give one command: ``default_map`` values and, per option flag, where each was set."""

    values: dict[str, object]
    sources: dict[str, str]

    def origin(self, message: str, argv: list[str]) -> str | None:
        """Where the option an error message starts with ('--dpi: ...') was set, unless the command line gave it."""
        flag = message.split(":", 1)[0].split(" ", 1)[0]
        where = self.sources.get(flag)
        if where is None:
            return None
        aliases = [alias for alias, place in self.sources.items() if place == where]
        given = any(arg == alias or arg.startswith(alias + "=") or (len(alias) == 2 and arg.startswith(alias))
                    for arg in argv for alias in aliases)
        return None if given else where


def command_defaults(files: list[DefaultsFile], name: str, command: click.Command) -> Defaults:
    """One command's defaults (parameter name -> value), later files overriding earlier ones."""
    options = {flag[2:]: param for param in command.params if isinstance(param, click.Option)
               for flag in param.opts + param.secondary_opts if flag.startswith("--")}
    defaults: dict[str, object] = {}
    sources: dict[str, str] = {}
    for source in files:
        for key, value in source.tables.get(name, {}).items():
            flag = key.replace("_", "-")
            where = f"{source.path}: [{name}] {key}"
            param = options.get(flag)
            if param is not None and flag in PER_RUN_OPTIONS:
                raise InputError(f"{where}: --{flag} acts on one run and is given on the command line only")
            if param is None:
                near = difflib.get_close_matches(flag, [k for k in options if k not in PER_RUN_OPTIONS], n=1)
                hint = f"did you mean {near[0]!r}?" if near else f"see 'heoslice {name} --help'"
                raise InputError(f"{where}: not an option of 'heoslice {name}' ({hint})")
            defaults[param.name] = _checked(param, value, where, source.path.parent, f"--{flag}" in param.secondary_opts)
            sources.update(dict.fromkeys(param.opts + param.secondary_opts, where))
    return Defaults(values=defaults, sources=sources)


def _checked(param: click.Option, value: object, where: str, folder: Path, secondary: bool = False) -> object:
    """``value`` converted by the option's own type, as the command line would; relative paths from ``folder``. A
    true/false flag's value is the flag's (``secondary``: the key is its off switch, ``rgba`` of
    ``--channels/--rgba``), whatever click keeps as the flag's own value (8.2 and later: an unset sentinel)."""
    if param.is_flag and not param.count:
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {value!r}")
        if getattr(param, "is_bool_flag", False) or isinstance(param.flag_value, bool):
            return value != secondary
        return param.flag_value if value else param.default
    if param.multiple or param.nargs != 1:
        if not isinstance(value, list):
            raise InputError(f"{where}: expected a list, e.g. {param.name} = [...], got {value!r}")
        if param.nargs != 1 and not param.multiple and len(value) != param.nargs:
            raise InputError(f"{where}: expected a list of {param.nargs} values, got {len(value)}")
        return [_scalar(param, item, where, folder) for item in value]
    return _scalar(param, value, where, folder)


def _scalar(param: click.Option, value: object, where: str, folder: Path) -> object:
    """One TOML number or string converted as its command-line text would be (``0.1`` -> '0.1' -> 0.1)."""
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise InputError(f"{where}: expected a number or a string, got {value!r}")
    text = value if isinstance(value, str) else repr(value)
    if isinstance(param.type, click.Path) and text:
        path = Path(text).expanduser()
        text = str(path if path.is_absolute() else folder / path)
    try:
        return param.type.convert(text, param, None)
    except click.BadParameter as err:
        raise InputError(f"{where}: {' '.join(str(err.message).split())}") from None


def load_defaults(explicit: Path | None, disabled: bool, group: click.Group, ctx: click.Context,
                  name: str) -> Defaults:
    """The defaults of running command ``name`` (only its table is checked; every file's table names are)."""
    files = [read_file(path, group.list_commands(ctx)) for path in find_files(explicit, disabled)]
    command = group.get_command(ctx, name)
    if command is None or not files:
        return Defaults(values={}, sources={})
    return command_defaults(files, name, command)
