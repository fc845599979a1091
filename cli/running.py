"""Running one parsed command and its exit code (`run`): this run's settings are built once
(`overrides.overridden`), what can be known to fail is checked before any work (an unwritable
output folder or .blend), the command runs (`commands.COMMANDS`), --save saves the .blend, and
each failure becomes its exit code (`codes`) and one line on stderr naming the file or option and
the fix; a bug prints its traceback (EXIT_INTERNAL).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback

import bpy

from ..core.errors import BakeError, DependencyMissing, FullBakeNeeded
from ..core.tracer import BakeCancelled
from .codes import (
    COMMAND,
    EXIT_CANCELLED,
    EXIT_DEPENDENCY,
    EXIT_FULL_BAKE,
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_OUTPUT,
)
from .commands import COMMANDS
from .option_types import soft_warnings
from .overrides import apply_options, overridden


class OutputProblem(Exception):
    """The output folder or the .blend cannot be written: EXIT_OUTPUT with this message."""


def output_problem(folder: str) -> str | None:
    """Why the files cannot be written into `folder` (created if missing), or None: checked
    before any work, so a bake does not run for minutes to fail at the end."""
    path = os.path.abspath(folder)
    if os.path.exists(path) and not os.path.isdir(path):
        return f"cannot write the output: {path} is a file, not a folder; give --out a folder path (made if missing)"
    existing = path
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        return f"cannot write the output: {existing} is a file, so the folder {path} cannot be made; give --out a folder path"
    if not os.access(existing, os.W_OK | os.X_OK):
        return (
            f"cannot write the output: no permission to write in {existing}; choose another --out, or make it writable"
        )
    return None


def save_problem() -> str | None:
    """Why --save cannot save the open .blend, or None (checked before the command runs)."""
    path = bpy.data.filepath
    if not bpy.data.is_saved or not path:
        return None  # a BakeError (input) in `save`
    if os.path.exists(path) and not os.access(path, os.W_OK):
        return f"--save: {path} is read-only: make it writable, or leave out --save (nothing was baked)"
    folder = os.path.dirname(path) or "."
    if not os.access(folder, os.W_OK | os.X_OK):
        return (
            f"--save: the folder {folder} is not writable (Blender saves through a temporary file there): "
            "make it writable, or leave out --save (nothing was baked)"
        )
    return None


def save(args) -> None:
    """--save: the .blend, after the command (its files are already written)."""
    if not bpy.data.is_saved:
        raise BakeError("--save: the .blend has never been saved, so there is no file to save to")
    try:
        bpy.ops.wm.save_mainfile()
    except RuntimeError as exc:
        detail = " ".join(str(exc).replace("Error:", "").split())
        raise OutputProblem(
            f"--save: cannot save {bpy.data.filepath}: {detail} (the {args.action}'s files were written; the "
            ".blend on disk is unchanged)"
        ) from None


def check_before(context, args, settings) -> None:
    """What can be known to fail before any work: an unwritable output folder or .blend (--save);
    `settings`: this run's (`overrides.overridden`)."""
    from ..bridge import bake_session

    if getattr(args, "save", False):
        if not bpy.data.is_saved:
            raise BakeError("--save: the .blend has never been saved, so there is no file to save to")
        problem = save_problem()
        if problem:
            raise OutputProblem(problem)
    # unwrap, uv-report and export write no bake files (--json, --glb are checked as they are written)
    if args.action not in ("unwrap", "uv-report", "export", "stale", "compare"):
        problem = output_problem(bake_session.output_folder(settings, args.out))
        if problem:
            raise OutputProblem(problem)


def os_problem(exc: OSError) -> str:
    """One line for an OSError met while writing: the file (not its temporary) and the fix."""
    import errno

    from ..core.files.exr import target_of

    name = target_of(exc.filename) if exc.filename else "the output"
    if exc.errno in (errno.EEXIST, errno.ENOTDIR):
        return f"cannot write {name}: a file stands where a folder is needed; give --out a folder path"
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"cannot write {name}: permission denied; choose another --out or make it writable"
    if exc.errno == errno.ENOSPC:
        return f"cannot write {name}: the disk is full; free some space and run again"
    return f"cannot write {name}: {exc.strerror or exc}"


def run(args: argparse.Namespace) -> int:
    """Run the parsed command on the open .blend; returns the exit code (never raises). SIGTERM
    is Ctrl-C here: the files being written are deleted, none is replaced (EXIT_CANCELLED)."""
    from ..core.console import terminate_as_interrupt

    context = bpy.context
    start = time.perf_counter()
    try:
        with terminate_as_interrupt():
            settings = overridden(context.scene, args)
            for w in soft_warnings(args):
                print(f"warning: {w}", flush=True)
            check_before(context, args, settings)
            summary = COMMANDS[args.action](context, args, settings)
            if getattr(args, "save", False):
                apply_options(context.scene.hhd, args)  # --save keeps this run's settings
                save(args)
    except DependencyMissing as exc:
        return fail(EXIT_DEPENDENCY, exc)
    except FullBakeNeeded as exc:
        return fail(EXIT_FULL_BAKE, exc)
    except (BakeCancelled, KeyboardInterrupt):
        return fail(EXIT_CANCELLED, "interrupted: no output file was replaced")
    except BakeError as exc:
        return fail(EXIT_INPUT, exc)
    except OutputProblem as exc:
        return fail(EXIT_OUTPUT, exc)
    except OSError as exc:
        return fail(EXIT_OUTPUT, f"{os_problem(exc)} (previous files are intact)")
    except Exception:  # a bug: say so, with the traceback, and a distinct code
        traceback.print_exc()
        return fail(EXIT_INTERNAL, "internal error (please report it with the traceback above)")
    print(f"{args.action}: {summary} [{time.perf_counter() - start:.1f} s]", flush=True)
    return EXIT_OK


def fail(code: int, message) -> int:
    """Print "hhd_lightmapper: error: `message`" on stderr; returns exit code `code`."""
    print(f"{COMMAND}: error: {message}", file=sys.stderr, flush=True)
    return code
