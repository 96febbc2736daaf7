"""Defaults files (``heoslice.toml``): where they are found, which wins, and one-line errors naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_cli_slice import write_box

from heoslice.errors import EXIT_INPUT


@pytest.fixture
def place(tmp_path, monkeypatch) -> Path:
    """A working directory with a 10 mm box, and an empty user config directory ($XDG_CONFIG_HOME)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    write_box(tmp_path / "box.off")
    return tmp_path


def user_file(place: Path, text: str) -> Path:
    path = place / "xdg" / "heoslice" / "heoslice.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def layers(run_cli, *options: str) -> int:
    """Slice the box with these group and slice options; the number of layers (10 mm / layer height)."""
    split = options.index("slice") if "slice" in options else -1
    group, command = options[:max(split, 0)], options[split + 1:]
    code, out, err = run_cli(*group, "slice", "box.off", "--force", "--json", "-j", "1", *command)
    assert code == 0, err
    return json.loads(out)["layers"]


def test_precedence_command_line_then_working_directory_then_user_file(run_cli, place):
    """Built-in 0.1 mm < user file < ./heoslice.toml (key by key) < the command line."""
    assert layers(run_cli, "--dpi", "25", "--layer", "2") == 5
    user_file(place, '[slice]\nlayer = 1\ndpi = "25"\n')
    assert layers(run_cli) == 10
    (place / "heoslice.toml").write_text("[slice]\nlayer = 2.5\n")
    assert layers(run_cli) == 4  # layer from ./heoslice.toml, dpi still from the user file
    assert layers(run_cli, "slice", "--layer", "5") == 2
    code, out, _ = run_cli("slice", "--help")
    assert "[default: 2.5]" in out


def test_config_file_replaces_both_and_no_config_reads_none(run_cli, place):
    """--config FILE reads only FILE; --no-config reads no file (the built-in defaults apply)."""
    user_file(place, "[slice]\nlayer = 1\n")
    (place / "heoslice.toml").write_text("[slice]\nlayer = 2\n")
    (place / "other.toml").write_text('[slice]\nlayer = 5\ndpi = "25"\n')
    assert layers(run_cli, "--config", "other.toml", "slice") == 2
    assert layers(run_cli, "--no-config", "slice", "--dpi", "25") == 100
    code, _, err = run_cli("--config", "other.toml", "--no-config", "slice", "box.off")
    assert code == EXIT_INPUT and "not both" in err


def test_print_table_sets_the_baud_rate(run_cli, place):
    """[print] baud applies to print (here its dry run's transfer time); --baud on the command line wins."""
    assert layers(run_cli, "slice", "--dpi", "25", "--layer", "1") == 10
    (place / "heoslice.toml").write_text("[print]\nbaud = 9600\n")
    seconds = {}
    for extra in ((), ("--baud", "96000")):
        code, out, err = run_cli("print", "box_stack", "--dry-run", "--json", *extra)
        assert code == 0, err
        seconds[extra] = json.loads(out)["seconds_at_baud"]
    assert seconds[()] == pytest.approx(10 * seconds[("--baud", "96000")])


@pytest.mark.parametrize(("text", "problem"), [
    ("[slice]\nlyer = 2\n", "heoslice.toml: [slice] lyer: not an option of 'heoslice slice' (did you mean 'layer'?)"),
    ("[slcie]\nlayer = 2\n", "heoslice.toml: [slcie] is not a heoslice command"),
    ('[slice]\nlayer = "thin"\n', "heoslice.toml: [slice] layer: 'thin' is not a valid float."),
    ("[slice]\nchannels = 1\n", "heoslice.toml: [slice] channels: expected true or false, got 1"),
    ("[slice]\ncompress = \"zip\"\n", "heoslice.toml: [slice] compress: 'zip' is not one of"),
    ("[print]\nbaud = 1.5\n", "heoslice.toml: [print] baud: '1.5' is not a valid integer range."),
    ("[slice]\nforce = true\n", "heoslice.toml: [slice] force: --force acts on one run"),
    ("[slice]\noutput = \"x\"\n", "heoslice.toml: [slice] output: --output acts on one run"),
    ("[slice]\ninto = \"/tmp\"\n", "heoslice.toml: [slice] into: --into acts on one run"),
    ("[print]\nlog = \"/etc/passwd\"\n", "heoslice.toml: [print] log: --log acts on one run"),
    ("layer = 2\n", "heoslice.toml: layer = ... is outside a table"),
    ("[slice\n", "heoslice.toml: not valid TOML (Expected ']'"),
    ("a = " + "[" * 5000 + "]" * 5000 + "\n", "heoslice.toml: arrays or tables nested too deeply"),
    ("a = " + "{b = " * 3000 + "1" + "}" * 3000 + "\n", "heoslice.toml: arrays or tables nested too deeply"),
])
def test_bad_files_are_one_line_naming_the_file(run_cli, place, text, problem):
    """Unknown tables and keys, per-run options, bad values and bad TOML: one line naming the file, exit 2."""
    (place / "heoslice.toml").write_text(text)
    command = "print" if "[print]" in text else "slice"
    code, out, err = run_cli(command, "box_stack" if command == "print" else "box.off", "--dry-run"
                             if command == "print" else "--json")
    assert code == EXIT_INPUT and out == ""
    assert err.count("\n") == 1 and err.startswith(f"heoslice: error: {problem}")
    assert not (place / "box_stack").exists()


def test_library_error_names_the_file_only_when_the_file_set_the_option(run_cli, place):
    """A value the command rejects later (--dpi x) says where it was set, unless the command line gave it."""
    (place / "heoslice.toml").write_text('[slice]\ndpi = "x"\n')
    code, _, err = run_cli("slice", "box.off")
    assert code == EXIT_INPUT and err.rstrip().endswith("(set in heoslice.toml: [slice] dpi)")
    code, _, err = run_cli("slice", "box.off", "--dpi=y")
    assert code == EXIT_INPUT and "'y'" in err and "set in" not in err


def test_relative_paths_are_read_from_the_files_folder(run_cli, place):
    """A path in the user's file (materials = "mats.toml") is beside that file, not in the working directory."""
    user = user_file(place, '[slice]\nmaterials = "mats.toml"\n')
    code, _, err = run_cli("slice", "box.off")
    assert code == EXIT_INPUT and str(user.parent / "mats.toml") in err


def test_a_defaults_files_volume_settings_leave_a_mesh_alone(run_cli, place):
    """A lab's ./heoslice.toml with volume settings ([slice] up, smooth, as) for its CT work still slices a mesh
    with them unused; typed on the command line with a mesh, the same options are refused."""
    (place / "heoslice.toml").write_text('[slice]\nup = "A"\nsmooth = 1.5\nas = "intensity"\n')
    assert layers(run_cli) == 100
    code, _, err = run_cli("slice", "box.off", "--force", "-j", "1", "--up", "A")
    assert code == EXIT_INPUT and "--up: only used when slicing a volume" in err


def test_every_true_false_flag_a_file_sets_is_applied():
    """Each true/false flag of every command, set true or false in a defaults file, is that value in the command's
    defaults (its off switch, --rgba of --channels/--rgba, the opposite), whatever click keeps as a flag's own
    value: a lab's `dry-run = true` must not be dropped (click 8.2 and later keep an unset sentinel there)."""
    import click

    from heoslice.cli import COMMANDS, cli
    from heoslice.cli.defaults import PER_RUN_OPTIONS, DefaultsFile, command_defaults

    with click.Context(cli) as ctx:
        checked = 0
        for name in COMMANDS:
            command = cli.get_command(ctx, name)
            for param in command.params:
                if not (isinstance(param, click.Option) and param.is_flag and not param.count):
                    continue
                for flag in (*param.opts, *param.secondary_opts):
                    if not flag.startswith("--") or flag[2:] in PER_RUN_OPTIONS:
                        continue
                    for value in (True, False):
                        file = DefaultsFile(Path("heoslice.toml"), {name: {flag[2:]: value}})
                        got = command_defaults([file], name, command).values[param.name]
                        assert got is (value != (flag in param.secondary_opts)), (name, flag, value, got)
                        checked += 1
    assert checked >= 20


def test_dry_run_set_in_a_file_does_not_print(run_cli, place):
    """`dry-run = true` in [print] makes `heoslice print STACK --port sim://` a dry run: nothing is sent, no print
    log is written."""
    assert layers(run_cli, "slice", "--dpi", "25", "--layer", "1") == 10
    (place / "heoslice.toml").write_text("[print]\ndry-run = true\n")
    code, out, err = run_cli("print", "box_stack", "--port", "sim://", "--json", "--log", place / "print.log")
    assert code == 0, err
    assert "seconds_at_baud" in json.loads(out) and not (place / "print.log").exists()
