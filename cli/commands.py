"""One function per command: `COMMANDS[name](context, args, settings)` runs it on the open .blend
and returns its summary line (printed last, with the time taken); warnings and progress go to
the console as it runs. `settings` is this run's settings (`overrides.overridden`: the scene's,
overridden by the options), read by every command instead of `scene.hhd`. A failure is raised
(`core.errors`); `running.run` turns it into an exit code.
"""

from __future__ import annotations

import os

import bpy

from ..bridge import settings as bridge_settings
from ..core.errors import BakeError
from .option_types import scheduler_problem


def unwrap(context, args, settings) -> str:
    """Unwrap the receivers with a progress line; Ctrl-C cancels (BakeCancelled, no mesh changed).
    A texel density no atlas can hold is refused before xatlas runs (`core.unwrap.atlas_limits`, in the
    core unwrap)."""
    from ..bridge import bake_session
    from ..core.console import ConsoleProgress, interrupt_as_cancel
    from ..core.progress import with_eta
    from ..operators import unwrap as unwrapping

    objects = bake_session.target_objects(context, args.objects, settings)
    if not objects:
        raise BakeError("no receivers: pass --objects or --collection, or save the .blend with them selected")
    job = unwrapping.read_objects(objects, settings, getattr(args, "make_single_user", False))
    print(f"unwrap: {len(objects)} object(s)", flush=True)
    progress = ConsoleProgress()
    try:
        with interrupt_as_cancel() as cancel:
            result = unwrapping.compute(job, with_eta(progress), cancel)
    finally:
        progress.close()
    summary, warnings = unwrapping.write_objects(job, settings, result)
    for w in warnings:
        print(f"warning: {w}")
    return summary


def bake(context, args, settings) -> str:
    """`bake`: every receiver (`bridge.bake_session.BakeSession`), unwrapped first with --unwrap,
    traced here or on the farm of --scheduler (else the scene's Dask Scheduler); --only and
    --changed bake a subset (`bake_subset`). Ctrl-C or SIGTERM cancels: no file replaced."""
    from ..bridge import bake_session
    from ..core.console import ConsoleProgress, interrupt_as_cancel
    from ..core.progress import with_eta

    if args.only or args.changed:
        return bake_subset(context, args, settings)
    if args.unwrap:
        print(unwrap(context, args, settings), flush=True)
    reading = ConsoleProgress(step=0.25)
    try:
        session = bake_session.BakeSession(
            context, args.objects, args.out, threads=args.threads, settings=settings, progress=with_eta(reading)
        )
    finally:
        reading.close()
    for w in session.warnings:
        print(f"warning: {w}")
    print(f"bake: {session.describe()}", flush=True)
    address = args.scheduler or session.scheduler.strip()  # the option, else the scene's Dask Scheduler
    if address and not args.scheduler and scheduler_problem(address):
        raise BakeError(
            f"the scene's Dask Scheduler setting {address!r} is not a scheduler address: "
            f"{scheduler_problem(address)}; fix it (Render > HHD Lightmapper) or pass --scheduler"
        )
    farm = connect_farm(address, session.settings.trace) if address else None
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


def bake_subset(context, args, settings) -> str:
    """`bake --only NAMES` / `--changed [--influenced]`: `bridge.incremental_session`."""
    from ..bridge import incremental_session
    from ..core.console import ConsoleProgress, interrupt_as_cancel

    mode = "only" if args.only else "influenced" if args.influenced else "changed"
    session = incremental_session.IncrementalSession(
        context, mode, args.only, args.out, threads=args.threads, settings=settings
    )
    for w in session.warnings:
        print(f"warning: {w}")
    print(f"bake: {session.describe()}", flush=True)
    progress = ConsoleProgress()
    try:
        with interrupt_as_cancel() as cancel:
            session.run(progress=progress, cancel=cancel)
    finally:
        progress.close()
    summary = session.finish()
    for w in session.result_warnings:
        print(f"warning: {w}")
    return summary


def stale(context, args, settings) -> str:
    """`stale`: what changed since the last bake (`bridge.incremental_session.stale_report`); it
    takes no option that overrides a scene setting (--out is its folder)."""
    from ..bridge import incremental_session

    _, lines = incremental_session.stale_report(context, args.out, settings)
    for line in lines[:-1]:
        print(f"stale: {line}")
    return lines[-1]


def connect_farm(address: str, trace):
    """The connected farm of --scheduler (core.farm: Dask imported only now), after refusing
    settings it cannot bake (a time budget)."""
    from ..core import farm

    farm.Farm.check(trace)
    connected = farm.connect(address)  # DependencyMissing without Dask, saying how to get it
    print(f"farm: {connected.workers()} worker(s) at {address}", flush=True)
    for w in connected.warnings:
        print(f"warning: {w}")
    return connected


def uv_report(context, args, settings) -> str:
    """`uv-report`: the views' figures (`shaders.texel_views.report`), printed and with --json
    written; the .blend is not changed. Receivers without the lightmap UV layer: EXIT_INPUT,
    named, after the report of the others."""
    import json

    from ..bridge import bake_session
    from ..shaders import texel_views

    objects = bake_session.target_objects(context, args.objects, settings)
    if not objects:
        raise BakeError("no receivers: pass --objects or --collection, or save the .blend with them selected")
    document, lines = texel_views.report(objects, settings)
    for line in lines:
        print(line)
    if args.json:
        path = os.path.abspath(args.json)
        text = json.dumps({"blend": bpy.data.filepath, **document}, indent=1, allow_nan=False) + "\n"
        temporary = f"{path}.{os.getpid()}.tmp"
        try:
            with open(temporary, "w", encoding="utf-8") as f:
                f.write(text)
            os.replace(temporary, path)
        finally:
            if os.path.exists(temporary):
                os.remove(temporary)
    missing = document["missing_uv_layer"]
    if missing:
        them = "it" if len(missing) == 1 else "them"
        raise BakeError(
            f"{', '.join(repr(n) for n in missing)} ha{'s' if len(missing) == 1 else 've'} no lightmap UV layer "
            f"'{settings.uv_layer}' (or no faces): unwrap {them} first, or leave {them} out of the "
            "receivers (the others are reported above)"
        )
    t = document["totals"]
    problems = t["shared_texels"] + t["flipped_faces"] + t["degenerate_faces"] + t["too_few_texels"]
    written = f"; JSON -> {os.path.abspath(args.json)}" if args.json else ""
    return (
        f"{t['objects']} object(s) in {len(document['atlases'])} atlas(es): {problems} problem(s): "
        f"{t['shared_texels']} texels shared by two charts, {t['flipped_faces']} flipped, "
        f"{t['degenerate_faces']} degenerate faces, {t['too_few_texels']} object(s) with too few texels{written}"
    )


def export(context, args, _view) -> str:
    """`export`: Blender's glTF exporter with the HHD hook (bridge/gltf_export.py), as File > Export;
    the lightmaps from --out, else the scene's Output Folder."""
    from ..bridge import gltf_export

    path = args.glb or args.gltf
    result = gltf_export.export(path, glb=bool(args.glb), out_dir=args.out)
    for w in result["warnings"]:
        print(f"warning: {w}")
    return f"{len(result['exported'])} object(s) with lightmaps -> {path}"


def encode(context, args, settings) -> str:
    """`encode`: the receivers' atlases encoded again from their SH EXRs
    (`operators.encode.reencode_objects`), with the settings value a bake of this run would take
    (`bridge.settings.scene_settings`: the encoder, denoise, stitch; --threads, else the scene's)."""
    from ..bridge import bake_session
    from ..operators import encode as reencoding

    objects = bake_session.target_objects(context, args.objects, settings)
    pipeline = bridge_settings.scene_settings(context.scene, args.threads, settings)
    summary, warnings = reencoding.reencode_objects(objects, settings, pipeline, args.out)
    for w in warnings:
        print(f"warning: {w}")
    return summary


def compare(context, args, settings) -> str:
    """`compare`: a progress line per step (each Cycles render, each atlas's post stages and
    encodings, the report); Ctrl-C or SIGTERM stops at the next step (within a denoise): no
    report file is replaced, the scene as it was (EXIT_CANCELLED)."""
    from ..bridge import compare as comparing
    from ..core.console import ConsoleProgress, interrupt_as_cancel

    if args.cycles_samples < 2 or not 1 <= args.percentage <= 100 or any(not 0.0 < r <= 1.0 for r in args.roughness):
        raise BakeError("compare: --cycles-samples ≥ 2, --percentage in 1–100 and --roughness in (0, 1]")
    job = comparing.prepare(
        context,
        args.objects,
        args.out,
        args.report,
        samples=args.cycles_samples,
        roughness=tuple(args.roughness),
        models=tuple(args.models or comparing.core_compare.MODELS),
        percentage=args.percentage,
        settings=settings,
    )
    print(f"compare: {len(job.steps)} steps into {job.report_dir}", flush=True)
    progress = ConsoleProgress(step=0.0)
    try:
        with interrupt_as_cancel() as cancel:
            summary, warnings = comparing.run_steps(job, progress, cancel)
    finally:
        progress.close()
    for w in warnings:
        print(f"warning: {w}")
    return summary


def blend(context, args, settings) -> str:
    """`blend`: the light sets' blend at --weights written into each atlas's lightmap
    (`bridge.light_sets.blend_objects`)."""
    from ..bridge import bake_session, light_sets

    objects = bake_session.target_objects(context, args.objects, settings)
    return light_sets.blend_objects(objects, settings, dict(args.weights), args.out)


#: Each command's function, by its name on the command line.
COMMANDS = {
    "unwrap": unwrap,
    "bake": bake,
    "encode": encode,
    "compare": compare,
    "blend": blend,
    "export": export,
    "uv-report": uv_report,
    "stale": stale,
}
