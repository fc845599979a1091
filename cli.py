"""Headless use: `blender -b scene.blend --command hhd_lightmapper <unwrap|bake|encode|blend> [options]`.

Registered with `bpy.utils.register_cli_command` when the extension is enabled. The same entry
point works with the `bpy` module from Python, without a Blender executable:

    python -m hhd_lightmapper.cli scene.blend bake --out lightmaps

(`standalone` opens the .blend and registers the add-on first). Exit codes are stable, so build
scripts can tell failures apart: see EXIT_* below; every failure prints one line saying why.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback

import bpy

from . import blender_compat
from .core import encoding, presets
from .core.errors import BakeError, DependencyMissing
from .core.tracer import BakeCancelled

COMMAND = "hhd_lightmapper"
EXIT_OK = 0
EXIT_INPUT = 1  # the scene or the options cannot be baked as given (message names what)
EXIT_USAGE = 2  # bad command line (argparse)
EXIT_DEPENDENCY = 3  # a compiled package (embreex, xatlas, OpenEXR), or Dask for --scheduler, is missing
EXIT_OUTPUT = 4  # the output files could not be written (previous files are intact)
EXIT_CANCELLED = 5  # interrupted (Ctrl-C): no file replaced
EXIT_INTERNAL = 70  # a bug: the traceback is printed


def _thread_count(text: str) -> int:
    """argparse type of --threads: a whole number ≥ 0 (0 = every core)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"invalid thread count {text!r}: give a whole number ≥ 0 (0 = all cores)"
        ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"invalid thread count {value}: it must be ≥ 0 (0 = all cores)")
    return value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=f"blender -b FILE.blend --command {COMMAND}",
        description="HHD Lightmapper: unwrap, bake and encode directional lightmaps.",
    )
    sub = p.add_subparsers(dest="action", required=True)

    def receivers(q):
        q.add_argument(
            "--objects",
            nargs="+",
            metavar="NAME",
            help="receiver objects (default: the scene's Receivers setting: the saved selection or collection)",
        )
        q.add_argument("--collection", metavar="NAME", help="receivers: the mesh objects of this collection")

    def threads(q):
        q.add_argument(
            "--threads",
            type=_thread_count,
            default=None,
            metavar="N",
            help="worker threads, 0 = every core this process may use (default: the scene's "
            "Render > Performance > Threads, as a headless Cycles render; Auto = every core)",
        )

    def encoder(q):
        q.add_argument("--model", choices=list(encoding.MODELS))
        q.add_argument("--direction", choices=list(encoding.DIRECTIONS))
        q.add_argument("--ambient", choices=list(encoding.AMBIENTS))
        q.add_argument("--phi-search", action="store_true", default=None)

    def denoise(q, what, default):
        q.add_argument(
            "--denoise",
            action=argparse.BooleanOptionalAction,
            default=None,
            help=f"{what} the SH denoised with Open Image Denoise's lightmap filter (Blender's own "
            f"library), or not (default: {default}); the SH EXR always keeps the SH as traced",
        )

    def stitch(q, what):
        q.add_argument(
            "--stitch",
            dest="stitch_seams",
            action=argparse.BooleanOptionalAction,
            default=None,
            help=f"{what} the SH stitched along the UV seams of smooth surfaces, so no line shows where a "
            "surface is split between charts, or not (default: the scene's Stitch Seams setting)",
        )

    q = sub.add_parser("unwrap", help="xatlas lightmap UVs for the receivers")
    receivers(q)
    q.add_argument("--resolution", type=int)
    q.add_argument("--texel-density", type=float)
    q.add_argument("--make-single-user", action="store_true")
    q.add_argument("--save", action="store_true", help="save the .blend afterwards (keeps the UVs)")

    q = sub.add_parser("bake", help="trace, encode and write the lightmap files")
    receivers(q)
    encoder(q)
    q.add_argument("--out", metavar="DIR", help="output folder (default: the scene's Output Folder)")
    q.add_argument("--preset", choices=[k.lower() for k in presets.PRESETS])
    q.add_argument("--samples", type=int)
    q.add_argument("--bounces", type=int)
    q.add_argument(
        "--noise-target",
        type=float,
        metavar="PERCENT",
        help="stop a texel once the standard error of its irradiance is below PERCENT of it",
    )
    q.add_argument("--time-budget", type=float, metavar="SECONDS", help="stop tracing after SECONDS")
    q.add_argument("--seed", type=int)
    denoise(q, "encode", "the --preset's, else the scene's Denoise setting")
    stitch(q, "encode")
    q.add_argument("--unwrap", action="store_true", help="unwrap the receivers first")
    q.add_argument("--resolution", type=int, help="atlas size for --unwrap")
    q.add_argument("--texel-density", type=float, help="texels per metre for --unwrap")
    q.add_argument("--save", action="store_true", help="save the .blend afterwards (keeps the loaded images)")
    q.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="trace on the Dask cluster of this scheduler (docs/farm.md): the same files as a local bake; "
        "finished tasks are kept in the output folder's .hhd_farm, so the same command resumes",
    )
    threads(q)

    q = sub.add_parser("encode", help="re-encode a finished bake from its SH EXR (no tracing)")
    receivers(q)
    encoder(q)
    q.add_argument("--out", metavar="DIR", help="folder of the bake (default: the scene's Output Folder)")
    denoise(q, "re-encode", "the scene's Denoise setting")
    stitch(q, "re-encode")
    threads(q)

    q = sub.add_parser(
        "blend", help="write the blended state of the light sets into each atlas's lightmap (no tracing)"
    )
    receivers(q)
    q.add_argument("--out", metavar="DIR", help="folder of the bake (default: the scene's Output Folder)")
    q.add_argument(
        "--weights",
        nargs="+",
        type=_weight,
        default=[],
        metavar="NAME=W",
        help="a light set's weight, W a number or R,G,B (≥ 0); sets not given keep the scene's weight (else 1)",
    )
    return p


def _weight(text: str) -> tuple[str, tuple[float, ...]]:
    """'NAME=W' or 'NAME=R,G,B' -> (NAME, weight)."""
    name, sep, value = text.partition("=")
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        parts = ()
    if not sep or not name or len(parts) not in (1, 3):
        raise argparse.ArgumentTypeError(f"expected NAME=W or NAME=R,G,B, got '{text}'")
    return name, parts if len(parts) == 3 else parts * 3


def _apply_options(settings, args) -> None:
    """Command-line options override the scene settings for this run (not saved unless --save)."""
    if getattr(args, "preset", None):  # first: explicit options below override it
        settings.preset = args.preset.upper()
    for key in (
        "resolution",
        "texel_density",
        "samples",
        "bounces",
        "noise_target",
        "time_budget",
        "seed",
        "phi_search",
        "denoise",
        "stitch_seams",
    ):
        value = getattr(args, key, None)
        if value is not None:
            setattr(settings, key, value)
    for key in ("model", "direction", "ambient"):
        value = getattr(args, key, None)
        if value is not None:
            setattr(settings, key, value.upper())
    if args.collection:
        if args.collection not in bpy.data.collections:
            raise BakeError(f"no collection named '{args.collection}'")
        settings.target, settings.target_collection = 'COLLECTION', bpy.data.collections[args.collection]


def _unwrap(context, args) -> str:
    """Unwrap the receivers with a progress line; Ctrl-C cancels (BakeCancelled, no mesh changed)."""
    from .bridge import bake_session
    from .core.console import ConsoleProgress, interrupt_as_cancel
    from .operators import unwrap

    objects = bake_session.target_objects(context, args.objects)
    if not objects:
        raise BakeError("no receivers: pass --objects or --collection, or save the .blend with them selected")
    print(f"unwrap: {len(objects)} object(s)", flush=True)
    progress = ConsoleProgress()
    try:
        with interrupt_as_cancel() as cancel:
            summary, warnings = unwrap.unwrap_objects(
                objects, context.scene.hhd, getattr(args, "make_single_user", False), progress, cancel
            )
    finally:
        progress.close()
    for w in warnings:
        print(f"warning: {w}")
    return summary


def _bake(context, args) -> str:
    from .bridge import bake_session
    from .core.console import ConsoleProgress, interrupt_as_cancel

    if args.unwrap:
        print(_unwrap(context, args), flush=True)
    session = bake_session.BakeSession(context, args.objects, args.out, threads=args.threads)
    for w in session.warnings:
        print(f"warning: {w}")
    print(f"bake: {session.describe()}", flush=True)
    address = args.scheduler or session.scheduler  # the option, else the scene's Dask Scheduler
    farm = _farm(address, session.settings.trace) if address else None
    progress = ConsoleProgress()
    try:
        with interrupt_as_cancel() as cancel:
            session.run(progress=progress, cancel=cancel, farm=farm)
    finally:
        progress.close()
        if farm is not None:
            farm.close()
    summary = session.finish()
    for w in session.result_warnings:  # e.g. no denoiser: the files are written undenoised
        print(f"warning: {w}")
    return summary


def _farm(address: str, trace):
    """The connected farm of --scheduler (core.farm: Dask imported only now), after refusing
    settings it cannot bake (a time budget)."""
    from .core import farm

    farm.Farm.check(trace)
    connected = farm.connect(address)  # DependencyMissing without Dask, saying how to get it
    print(f"farm: {connected.workers()} worker(s) at {address}", flush=True)
    for w in connected.warnings:
        print(f"warning: {w}")
    return connected


def _encode(context, args) -> str:
    from .bridge import bake_session
    from .operators import encode

    objects = bake_session.target_objects(context, args.objects)
    threads = bake_session.scene_threads(context.scene) if args.threads is None else args.threads
    summary, warnings = encode.reencode_objects(objects, context.scene.hhd, args.out, threads=threads)
    for w in warnings:
        print(f"warning: {w}")
    return summary


def _blend(context, args) -> str:
    from .bridge import bake_session, light_sets

    objects = bake_session.target_objects(context, args.objects)
    return light_sets.blend_objects(objects, context.scene.hhd, dict(args.weights), args.out)


def main(argv: list[str]) -> int:
    """Run one command; returns the exit code (never raises)."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return EXIT_USAGE if exc.code else EXIT_OK
    context = bpy.context
    start = time.perf_counter()
    try:
        _apply_options(context.scene.hhd, args)
        summary = {"unwrap": _unwrap, "bake": _bake, "encode": _encode, "blend": _blend}[args.action](context, args)
        if getattr(args, "save", False):
            if not bpy.data.is_saved:
                raise BakeError("--save: the .blend has never been saved, so there is no file to save to")
            bpy.ops.wm.save_mainfile()
    except DependencyMissing as exc:
        return _fail(EXIT_DEPENDENCY, exc)
    except (BakeCancelled, KeyboardInterrupt):
        return _fail(EXIT_CANCELLED, "interrupted: no output file was replaced")
    except BakeError as exc:
        return _fail(EXIT_INPUT, exc)
    except OSError as exc:
        return _fail(EXIT_OUTPUT, f"cannot write the output: {exc} (previous files are intact)")
    except Exception:  # a bug: say so, with the traceback, and a distinct code
        traceback.print_exc()
        return _fail(EXIT_INTERNAL, "internal error (please report it with the traceback above)")
    print(f"{args.action}: {summary} [{time.perf_counter() - start:.1f} s]", flush=True)
    return EXIT_OK


def _fail(code: int, message) -> int:
    print(f"{COMMAND}: error: {message}", file=sys.stderr, flush=True)
    return code


def standalone(argv: list[str]) -> int:
    """`python -m hhd_lightmapper.cli FILE.blend <command> ...` under the bpy module."""
    if not argv or not argv[0].endswith(".blend"):
        print("usage: python -m hhd_lightmapper.cli FILE.blend {unwrap,bake,encode} ...", file=sys.stderr)
        return EXIT_USAGE
    try:
        bpy.ops.wm.open_mainfile(filepath=argv[0])
    except RuntimeError as exc:
        return _fail(EXIT_INPUT, f"cannot open {argv[0]}: {exc}")
    import hhd_lightmapper

    hhd_lightmapper.register()
    try:
        return main(argv[1:])
    finally:
        hhd_lightmapper.unregister()


_handle = None


def register():
    global _handle
    _handle = bpy.utils.register_cli_command(COMMAND, main)


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None


if __name__ == "__main__":
    blender_compat.exit_process(standalone(sys.argv[1:]))
