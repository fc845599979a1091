"""Headless use: `blender -b scene.blend --command hhd_lightmapper <unwrap|bake|encode|blend|uv-report|export> [options]`.

Registered with `bpy.utils.register_cli_command` when the extension is enabled. The same entry
point works with the `bpy` module from Python, without a Blender executable:

    python -m hhd_lightmapper.cli scene.blend bake --out lightmaps

(`standalone` parses the command line, then opens the .blend and registers the add-on). `--help`,
at the top or after a command, lists every command and option without a .blend. Exit codes are
stable, so build scripts can tell failures apart: see EXIT_* (`codes`); every failure prints one
line saying why: the file or option, the problem and the fix (README: "Exit codes and what the
bake refuses").

The package, by job: `codes` the name, calling forms and exit codes; `options` the parser, with
`option_types` what each option takes; `overrides` the options as this run's settings;
`commands` one function per command; `running` a parsed command run to its exit code. This file
holds the entry points and imports neither bpy nor numpy until one is called, so that
`python -m hhd_lightmapper.cli` (`__main__`) can catch a stop signal while they load.
"""

from __future__ import annotations

import sys

from .codes import (
    BLENDER_PROG,
    COMMAND,
    EXIT_CANCELLED,
    EXIT_CODES,
    EXIT_DEPENDENCY,
    EXIT_FULL_BAKE,
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_OUTPUT,
    EXIT_USAGE,
    STANDALONE_PROG,
)

__all__ = [
    "BLENDER_PROG",
    "COMMAND",
    "EXIT_CANCELLED",
    "EXIT_CODES",
    "EXIT_DEPENDENCY",
    "EXIT_FULL_BAKE",
    "EXIT_INPUT",
    "EXIT_INTERNAL",
    "EXIT_OK",
    "EXIT_OUTPUT",
    "EXIT_USAGE",
    "STANDALONE_PROG",
    "main",
    "register",
    "standalone",
    "unregister",
]


def main(argv: list[str]) -> int:
    """Run one command on the open .blend; returns the exit code (never raises). Blender's entry
    point (`blender -b FILE.blend --command hhd_lightmapper ...`): `--help` prints the help."""
    from .options import parse, parser
    from .running import run

    args = parse(parser(BLENDER_PROG), argv)
    return args if isinstance(args, int) else run(args)


def standalone(argv: list[str]) -> int:
    """`python -m hhd_lightmapper.cli FILE.blend <command> ...` under the bpy module. The command
    line is parsed before the .blend is opened: `--help` (with or without FILE.blend, at the top or
    after a command) and usage errors never open a file."""
    from ..core.console import terminate_as_interrupt
    from .running import fail

    with terminate_as_interrupt():  # the start-up's handlers (exit_on_stop_signal) end here
        try:
            return _standalone(argv)
        except KeyboardInterrupt:  # while opening the .blend or registering: nothing written
            return fail(EXIT_CANCELLED, "interrupted while starting: nothing was written")


def _standalone(argv: list[str]) -> int:
    import bpy

    from .options import commands, parse, parser
    from .running import fail, run

    p = parser(STANDALONE_PROG)
    has_blend = bool(argv) and argv[0].endswith(".blend")
    if argv and not has_blend and not argv[0].startswith("-") and argv[0] not in commands(p):
        p.print_usage(sys.stderr)  # a file that is not a .blend, or a misspelt command
        return fail(EXIT_USAGE, f"expected FILE.blend or a command first, got {argv[0]!r}")
    args = parse(p, argv[1:] if has_blend else argv)
    if isinstance(args, int):
        return args
    if not has_blend:
        p.print_usage(sys.stderr)
        return fail(EXIT_USAGE, "the first argument must be the .blend file to open (FILE.blend)")
    try:
        bpy.ops.wm.open_mainfile(filepath=argv[0])
    except RuntimeError as exc:
        return fail(EXIT_INPUT, f"cannot open {argv[0]}: {exc}")
    import hhd_lightmapper

    hhd_lightmapper.register()
    try:
        return run(args)
    finally:
        hhd_lightmapper.unregister()


_handle = None


def register():
    """Register `main` as Blender's `--command hhd_lightmapper` (the extension's register)."""
    import bpy

    global _handle
    _handle = bpy.utils.register_cli_command(COMMAND, main)


def unregister():
    import bpy

    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
