"""The command line explains itself (issue 54): `--help` at the top and after every command lists
every command and option with what it does and its default, without a .blend (and without
opening one when a .blend is given), for both entry points: Blender's (`cli.main`, registered
with `bpy.utils.register_cli_command`) and `python -m hhd_lightmapper.cli` (`cli.standalone`).

The commands and options checked are walked from the argparse parser, so a new one is covered
without editing this file. All in-process but one: the subprocess test checks the process
boundary of `python -m hhd_lightmapper.cli --help` (exit status, output, no .blend needed).
"""

import argparse
import os
import re
import subprocess
import sys

import pytest

from hhd_lightmapper import cli
from hhd_lightmapper.cli import options

pytestmark = pytest.mark.bpy

# entry point -> (function, the prog its help should name)
ENTRIES = {
    "blender": (cli.main, cli.BLENDER_PROG),
    "standalone": (cli.standalone, cli.STANDALONE_PROG),
}


@pytest.fixture(autouse=True)
def fixed_width(monkeypatch):
    """argparse wraps at the terminal's width: make it the same wherever the tests run."""
    monkeypatch.setenv("COLUMNS", "80")


def commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The subparsers of `parser` by command name, walked from its actions."""
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def command_help(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Each command's one-line description in the top-level listing."""
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a.help for a in sub._choices_actions}


def usage(text: str) -> str:
    """The usage paragraph of a help or error output (up to its first blank line)."""
    start = text.index("usage:")
    return text[start:].split("\n\n")[0]


def exit_codes() -> dict[str, int]:
    """Every EXIT_* constant of the module."""
    return {name: value for name, value in vars(cli).items() if name.startswith("EXIT_") and isinstance(value, int)}


def assert_top_level_help(text: str, prog: str) -> None:
    parser = options.parser(prog)
    names = list(commands(parser))
    assert set(names) == {"unwrap", "bake", "encode", "compare", "blend", "uv-report", "export", "stale"}
    head = usage(text)
    assert head.startswith(f"usage: {prog} ")
    assert "{" + ",".join(names) + "}" in head, head  # the usage line lists every command
    for name, description in command_help(parser).items():
        assert description, f"command {name} has no description"
        assert re.search(rf"^\s+{name}\s+{re.escape(description.split()[0])}", text, re.M), (name, text)
    assert f"{cli.BLENDER_PROG} COMMAND [options]" in text  # both ways to call it
    assert f"{cli.STANDALONE_PROG} COMMAND [options]" in text
    assert_exit_codes(text)


def assert_exit_codes(text: str) -> None:
    epilog = text[text.index("exit codes:") :]
    for name, code in exit_codes().items():
        assert re.search(rf"^\s+{code}  \w", epilog, re.M), f"{name} = {code} is not in the exit-code table"


@pytest.mark.parametrize("entry", ENTRIES)
@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_top_level_help_lists_every_command_and_how_to_call_it(entry, flag, capsys):
    """`--help` / `-h` with no .blend prints the full help on stdout and exits 0."""
    run, prog = ENTRIES[entry]
    assert run([flag]) == cli.EXIT_OK
    out, err = capsys.readouterr()
    assert err == ""
    assert_top_level_help(out, prog)


@pytest.mark.parametrize("entry", ENTRIES)
def test_no_arguments_print_the_full_help_as_a_usage_error(entry, capsys):
    run, prog = ENTRIES[entry]
    assert run([]) == cli.EXIT_USAGE
    out, err = capsys.readouterr()
    assert out == ""
    assert_top_level_help(err, prog)


@pytest.mark.parametrize("entry", ENTRIES)
@pytest.mark.parametrize("command", list(commands(options.parser())))
def test_each_command_help_lists_every_option_with_its_default(entry, command, capsys):
    """`COMMAND --help` (no .blend) lists every option string of the command, each option's help
    says its default, and the exit codes follow."""
    run, prog = ENTRIES[entry]
    assert run([command, "--help"]) == cli.EXIT_OK
    out, err = capsys.readouterr()
    assert err == ""
    assert usage(out).startswith(f"usage: {prog} {command}")
    subparser = commands(options.parser(prog))[command]
    assert subparser.description and subparser.description in out
    for action in subparser._actions:
        for option in action.option_strings:
            assert re.search(rf"(^|[\s\[,]){re.escape(option)}\b", out), f"{command}: {option} missing from the help"
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help, f"{command} {action.option_strings} has no help"
        assert "default" in action.help, f"{command} {action.option_strings}: the help does not say the default"
    assert_exit_codes(out)


def test_help_quotes_the_scene_settings_ranges_and_defaults(capsys):
    """The options that override a numeric scene setting give its range and its value in a new
    scene, as properties.py declares them."""
    from hhd_lightmapper.properties import HHDSettings

    checked = 0
    for command, subparser in commands(options.parser()).items():
        for action in subparser._actions:
            prop = HHDSettings.__annotations__.get(action.dest)
            if prop is None or "min" not in prop.keywords or isinstance(prop.keywords["default"], bool):
                continue
            text = " ".join(action.help.split())
            keywords = prop.keywords
            assert f"{keywords['min']:g}" in text, (command, action.dest, text)
            if "max" in keywords:
                assert f"{keywords['min']:g}–{keywords['max']:g}" in text, (command, action.dest, text)
            assert f"{keywords['name']} setting, {keywords['default']:g}" in text, (command, action.dest, text)
            checked += 1
    assert checked >= 8  # resolution, texel density (twice each), samples, bounces, noise target, ...


def test_help_after_a_blend_does_not_open_it(tmp_path, capsys):
    """`FILE.blend --help` and `FILE.blend bake --help` print the help without opening the file:
    this one does not exist, so opening it would exit with EXIT_INPUT."""
    import bpy

    missing = str(tmp_path / "missing.blend")
    before = bpy.data.filepath
    assert cli.standalone([missing, "--help"]) == cli.EXIT_OK
    assert_top_level_help(capsys.readouterr().out, cli.STANDALONE_PROG)
    assert cli.standalone([missing, "bake", "--help"]) == cli.EXIT_OK
    out = capsys.readouterr().out
    assert usage(out).startswith(f"usage: {cli.STANDALONE_PROG} bake") and "--samples" in out
    assert bpy.data.filepath == before


@pytest.mark.parametrize(
    "argv, message",
    [
        (["MISSING", "bake", "--samples", "many"], "invalid int value"),  # checked before the file is opened
        (["MISSING", "frobnicate"], "invalid choice"),
        (["bake"], "FILE.blend"),  # a valid command line, but no .blend to run it on
        (["scene.txt", "bake"], "'scene.txt'"),
        (["MISSING"], "usage:"),  # a .blend and no command: the full help, as a usage error
    ],
)
def test_standalone_usage_errors_exit_2_without_opening_the_blend(argv, message, tmp_path, capsys):
    argv = [str(tmp_path / "missing.blend") if a == "MISSING" else a for a in argv]
    assert cli.standalone(argv) == cli.EXIT_USAGE
    out, err = capsys.readouterr()
    assert message in err and usage(err).startswith(f"usage: {cli.STANDALONE_PROG}"), err
    assert "cannot open" not in err


@pytest.mark.parametrize("argv", [["frobnicate"], ["bake", "--bogus"], ["blend", "--weights", "Red"]])
def test_blender_entry_usage_errors_exit_2(argv, capsys):
    assert cli.main(argv) == cli.EXIT_USAGE
    assert usage(capsys.readouterr().err).startswith(f"usage: {cli.BLENDER_PROG}")


def test_python_m_help_without_a_blend(tmp_path):
    """The process boundary: `python -m hhd_lightmapper.cli --help` in a folder with no .blend
    prints the full help and exits 0."""
    proc = subprocess.run(
        [sys.executable, "-m", "hhd_lightmapper.cli", "--help"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "80"},
    )
    assert proc.returncode == cli.EXIT_OK, proc.stderr
    assert "Traceback" not in proc.stderr
    assert_top_level_help(proc.stdout, cli.STANDALONE_PROG)
