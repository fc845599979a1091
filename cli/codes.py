"""The command line's stable surface without bpy: the command's name, its two calling forms and
its exit codes, so build scripts can tell failures apart (README: "Exit codes and what the bake
refuses"). Imports nothing, so `python -m hhd_lightmapper.cli` can catch a stop signal before
bpy and numpy load (`cli/__main__.py`).
"""

COMMAND = "hhd_lightmapper"
EXIT_OK = 0
EXIT_INPUT = 1  # the scene or the options cannot be baked as given (message names what)
EXIT_USAGE = 2  # bad command line (argparse)
EXIT_DEPENDENCY = 3  # a compiled package (embreex, xatlas, OpenEXR), or Dask for --scheduler, is missing
EXIT_OUTPUT = 4  # the output files could not be written (previous files are intact)
EXIT_CANCELLED = 5  # interrupted (Ctrl-C, SIGTERM): no file replaced
EXIT_FULL_BAKE = 6  # bake --only/--changed cannot go into the last bake's files (none, re-unwrapped): bake all
EXIT_INTERNAL = 70  # a bug: the traceback is printed

BLENDER_PROG = f"blender -b FILE.blend --command {COMMAND}"  # main(), registered with Blender
STANDALONE_PROG = "python -m hhd_lightmapper.cli FILE.blend"  # standalone(), under the bpy module

#: Every exit code with its meaning, for the help's epilog (the EXIT_* constants above).
EXIT_CODES = (
    (EXIT_OK, "ok: the command finished (its summary is the last line on stdout)"),
    (
        EXIT_INPUT,
        "input: the scene, a file read (a damaged or mismatched bake) or the options together cannot be "
        "baked as given (the message names what and the fix)",
    ),
    (
        EXIT_USAGE,
        "usage: bad command line (unknown command or option, a value out of its range, conflicting "
        "options, no FILE.blend)",
    ),
    (EXIT_DEPENDENCY, "dependency: a compiled package (embreex, xatlas, OpenEXR), or Dask for --scheduler, is missing"),
    (
        EXIT_OUTPUT,
        "output: the output folder or the .blend (--save) cannot be written (previous files are intact)",
    ),
    (EXIT_CANCELLED, "cancelled: interrupted (Ctrl-C or SIGTERM); no output file was replaced"),
    (
        EXIT_FULL_BAKE,
        "full bake needed: bake --only/--changed found no earlier bake, or the atlas layout or bake settings "
        "changed since it; nothing was written",
    ),
    (EXIT_INTERNAL, "internal error: a bug; the traceback is printed (please report it)"),
)
