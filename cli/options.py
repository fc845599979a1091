"""The argparse parser of both entry points (`parser`), and reading a command line with it
(`parse`): every command and option says what it does, its unit or range, and its default, which
come from the scene settings the options override (`option_types`). Reads no .blend.
"""

from __future__ import annotations

import argparse
import sys

from ..core import encoding, presets
from ..core.light_sets import MAX_WEIGHT
from .codes import (
    BLENDER_PROG,
    EXIT_CANCELLED,
    EXIT_CODES,
    EXIT_FULL_BAKE,
    EXIT_INPUT,
    EXIT_OK,
    EXIT_USAGE,
    STANDALONE_PROG,
)
from .option_types import (
    MAX_THREADS,
    choice_help,
    conflicts,
    default,
    new_scene_value,
    ranged,
    scheduler,
    span,
    thread_count,
    weight,
)


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's and epilog's lines (the calling forms, the exit-code table) as
    written; option help is wrapped as usual, but never inside a hyphenated word such as an
    option's name (--noise-target)."""

    def _split_lines(self, text, width):
        import textwrap

        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)


def parser(prog: str = BLENDER_PROG) -> argparse.ArgumentParser:
    """The command line of both entry points; `prog` names the one in use (BLENDER_PROG or
    STANDALONE_PROG). Every option says what it does, its unit or range, and its default."""
    exit_codes = "exit codes:\n" + "\n".join(f"  {code:>3}  {text}" for code, text in EXIT_CODES)
    p = argparse.ArgumentParser(
        prog=prog,
        formatter_class=_HelpFormatter,
        description="HHD Lightmapper: unwrap, bake and encode directional lightmaps of a .blend, headless.\n"
        "\n"
        "Run it with Blender, the extension installed and enabled:\n"
        f"  {BLENDER_PROG} COMMAND [options]\n"
        "or with the bpy module from Python (no Blender executable needed):\n"
        f"  {STANDALONE_PROG} COMMAND [options]\n"
        "\n"
        "Options override the .blend's HHD Lightmapper settings for this run only (--save keeps them);\n"
        "an option left out keeps the .blend's setting. COMMAND --help lists a command's options.",
        epilog=exit_codes,
    )
    sub = p.add_subparsers(dest="action", required=True, title="commands")

    for name, text, add_options in COMMANDS:
        add_options(
            sub.add_parser(name, help=text, description=text, epilog=exit_codes, formatter_class=_HelpFormatter)
        )
    return p


def commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The commands of `parser`, by name: its subparsers."""
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace | int:
    """The parsed command line, or the exit code once argparse has printed the help (EXIT_OK) or
    a usage error (EXIT_USAGE). No arguments at all print the full help, as a usage error."""
    if not argv:
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    try:
        args = parser.parse_args(argv)
        conflict = conflicts(args)
        if conflict:
            commands(parser)[args.action].error(conflict)  # usage line and message, SystemExit(2)
        return args
    except SystemExit as exc:
        return EXIT_USAGE if exc.code else EXIT_OK


# ---------------------------------------------------------------- options several commands take


def _receivers(q):
    """--objects, --collection: the receivers."""
    q.add_argument(
        "--objects",
        nargs="+",
        metavar="NAME",
        help="receiver objects, by name (mesh objects, or Empties that instance a collection: its objects, "
        "each named '<Empty>/<object>'; not with --collection) (default: the scene's "
        "Receivers setting: the selection saved in the .blend, or its receiver collection)",
    )
    q.add_argument(
        "--collection",
        metavar="NAME",
        help="receivers: the mesh objects (and collection instances) of this collection, child collections "
        "included; not with "
        "--objects (default: the scene's Receivers setting)",
    )


def _threads(q):
    """--threads: worker threads, 0 = every core."""
    q.add_argument(
        "--threads",
        type=thread_count,
        default=None,
        metavar="N",
        help=f"worker threads, 0–{MAX_THREADS}; 0 = every core this process may use (default: the scene's "
        "Render > Performance > Threads, as a headless Cycles render; Auto = every core)",
    )


def _encoder(q):
    """--model, --solve, --direction, --ambient, --phi-search: the encoding written."""
    q.add_argument(
        "--model",
        choices=list(encoding.MODELS),
        help=f"the encoding written: {choice_help('model', encoding.MODELS)} ({default('model')})",
    )
    q.add_argument(
        "--solve",
        choices=list(encoding.SOLVES),
        help=f"how an SG encoding fits its lobes: {choice_help('solve', encoding.SOLVES)} ({default('solve')})",
    )
    q.add_argument(
        "--direction",
        choices=list(encoding.DIRECTIONS),
        help=f"how the highlight direction is found: {choice_help('direction', encoding.DIRECTIONS)} "
        f"({default('direction')})",
    )
    q.add_argument(
        "--ambient",
        choices=list(encoding.AMBIENTS),
        help=f"ambient weight: {choice_help('ambient', encoding.AMBIENTS)} ({default('ambient')})",
    )
    q.add_argument(
        "--phi-search",
        action="store_true",
        default=None,
        help=f"also search the highlight direction's azimuth (slower, slightly lower error) ({default('phi_search')})",
    )


def _denoise(q, what, default_text):
    """--denoise/--no-denoise; `what` the command does with the SH, `default_text` where the default comes from."""
    q.add_argument(
        "--denoise",
        action=argparse.BooleanOptionalAction,
        default=None,
        help=f"{what} the SH denoised with Open Image Denoise's lightmap filter (Blender's own "
        f"library), or not (default: {default_text}, {new_scene_value('denoise')} in a new scene); the SH "
        "EXR always keeps the SH as traced",
    )


def _stitch(q, what):
    """--stitch/--no-stitch; `what` the command does with the SH."""
    q.add_argument(
        "--stitch",
        dest="stitch_seams",
        action=argparse.BooleanOptionalAction,
        default=None,
        help=f"{what} the SH stitched along the UV seams of smooth surfaces, so no line shows where a "
        f"surface is split between charts, or not ({default('stitch_seams')})",
    )


def _out(q, what):
    """--out: the bake's folder, `what` it is for this command."""
    q.add_argument(
        "--out",
        metavar="DIR",
        help=f"{what}; // at the start = relative to the .blend ({default('output_dir')})",
    )


def _resolution(q, what):
    """--resolution: the atlas size, `what` it is for this command."""
    q.add_argument(
        "--resolution",
        type=ranged("resolution", int),
        metavar="TEXELS",
        help=f"atlas width and height in texels, {span('resolution')}: {what} ({default('resolution')})",
    )


def _texel_density(q, what):
    """--texel-density: texels per metre, `what` it is for this command."""
    q.add_argument(
        "--texel-density",
        type=ranged("texel_density"),
        metavar="PER_METRE",
        help=f"texels per metre, {span('texel_density')}, {what}; 0 = use --resolution instead (only "
        "one of the two may be given) "
        f"({default('texel_density')})",
    )


# ---------------------------------------------------------------- each command's options


def _unwrap(q):
    _receivers(q)
    _resolution(q, "the size of every atlas when the texel density is 0")
    _texel_density(q, "sizing each atlas to its surface area")
    q.add_argument(
        "--make-single-user",
        action="store_true",
        help="give linked duplicates (objects sharing one mesh) their own mesh first; without it they stay "
        "linked and share the mesh's lightmap UVs, each with its own rectangle of the atlas (default: off)",
    )
    q.add_argument(
        "--save",
        action="store_true",
        help="save the .blend afterwards, keeping the UVs and this run's settings (default: off: the .blend "
        "on disk is left as it was)",
    )


def _bake(q):
    _receivers(q)
    _encoder(q)
    _out(q, "output folder")
    _preset(q)
    _trace(q)
    _denoise(q, "encode", "the --preset's, else the scene's Denoise setting")
    _stitch(q, "encode")
    q.add_argument(
        "--inward-faces",
        choices=["open-side", "as-modelled", "refuse"],
        help="faces whose normals point into their own closed object (an inside-out mesh): open-side "
        "bakes them on the side light reaches (n_v turned round, as Cycles shades them), as-modelled "
        f"bakes them as they are (black there) with a warning, refuse exits with code {EXIT_INPUT} naming "
        "them; a closed object holding a light is a room seen from inside and left alone "
        f"({default('inward_faces')})",
    )
    q.add_argument(
        "--unwrap",
        action="store_true",
        help="unwrap the receivers first, as the unwrap command does (linked duplicates and collection instances "
        "become instances) "
        "(default: off: bake the lightmap UVs the objects have)",
    )
    _resolution(
        q,
        "for --unwrap when the texel density is 0, and the atlas size of receivers whose lightmap UVs "
        "were not made by this add-on's unwrap",
    )
    _texel_density(q, "for --unwrap")
    q.add_argument(
        "--save",
        action="store_true",
        help="save the .blend afterwards, keeping the loaded images and this run's settings (default: off)",
    )
    q.add_argument(
        "--scheduler",
        type=scheduler,
        metavar="tcp://HOST:PORT",
        help="trace on the Dask cluster of this scheduler (docs/farm.md): the same files as a local bake; "
        "finished tasks are kept in the output folder's .hhd_farm, so the same command resumes "
        "(default: the scene's Dask Scheduler setting; empty, as in a new scene: bake on this machine)",
    )
    _partial(q)
    _threads(q)


def _preset(q):
    """bake --preset: the quality presets (`core.presets`), each described."""
    names = ", ".join(
        f"{k.lower()} ({p.samples} samples, {p.bounces} bounce{'s' * (p.bounces != 1)}, "
        f"{'denoised' if p.denoise else 'not denoised'})"
        for k, p in presets.PRESETS.items()
    )
    q.add_argument(
        "--preset",
        choices=[k.lower() for k in presets.PRESETS],
        help=f"quality preset, setting --samples, --bounces, --noise-target and --denoise (any of them given "
        f"as well overrides it): {names}; README: Speed vs accuracy (default: none: the scene's own "
        "Samples, Bounces, Noise Target and Denoise settings)",
    )


def _trace(q):
    """bake's tracer options: --samples, --bounces, --noise-target, --time-budget, --seed."""
    q.add_argument(
        "--samples",
        type=ranged("samples", int),
        metavar="N",
        help=f"hemisphere samples per texel (the most a texel takes with --noise-target), {span('samples')} "
        f"({default('samples')})",
    )
    q.add_argument(
        "--bounces",
        type=ranged("bounces", int),
        metavar="N",
        help=f"diffuse interreflection bounces after the first hit, {span('bounces')} ({default('bounces')})",
    )
    q.add_argument(
        "--noise-target",
        type=ranged("noise_target"),
        metavar="PERCENT",
        help="stop a texel once the standard error of its irradiance is below PERCENT of it, "
        f"{span('noise_target')}; 0 = every texel takes every sample ({default('noise_target')})",
    )
    q.add_argument(
        "--time-budget",
        type=ranged("time_budget", unit=" s"),
        metavar="SECONDS",
        help=f"stop tracing after SECONDS, {span('time_budget')} (the first pass always completes); "
        f"0 = no limit ({default('time_budget', ' s')})",
    )
    q.add_argument(
        "--seed",
        type=ranged("seed", int),
        metavar="N",
        help=f"random seed, {span('seed')}: the same seed gives the same bake ({default('seed')})",
    )


def _partial(q):
    """bake --only, --changed, --influenced: a partial bake into the last bake's files."""
    q.add_argument(
        "--only",
        nargs="+",
        metavar="NAME",
        help="re-trace only these receivers of the last bake in the output folder and write their texels into "
        f"its files, every other texel kept as it is (README: Bake what changed); exit code {EXIT_FULL_BAKE} "
        "when there is no earlier bake or the layout changed (default: off: bake every receiver)",
    )
    q.add_argument(
        "--changed",
        action="store_true",
        help="as --only, for the receivers whose geometry, transform or material changed since the last bake "
        "(the stale command lists them) (default: off)",
    )
    q.add_argument(
        "--influenced",
        action="store_true",
        help="with --changed: also the receivers the changes (objects, lights, world) influence, by the rule in "
        "README: Bake what changed (default: off)",
    )


def _stale(q):
    _out(q, "folder of the bake")


def _encode(q):
    _receivers(q)
    _encoder(q)
    _out(q, "folder of the bake")
    _denoise(q, "re-encode", "the scene's Denoise setting")
    _stitch(q, "re-encode")
    _threads(q)


def _compare(q):
    _receivers(q)
    _out(q, "folder of the bake")
    q.add_argument(
        "--report",
        metavar="DIR",
        help="folder for compare.md, compare.json, contact_sheet.png (default: <out>/compare)",
    )
    q.add_argument(
        "--cycles-samples",
        type=int,
        default=256,
        metavar="N",
        help="Cycles samples of each reference (two renders of N/2 with other seeds) (default: 256)",
    )
    q.add_argument(
        "--roughness",
        type=float,
        nargs="*",
        default=[0.25, 0.5, 0.75],
        metavar="R",
        help="GGX roughness values of the specular comparison, α = R² (default: 0.25 0.5 0.75; none: diffuse only)",
    )
    q.add_argument(
        "--models",
        nargs="+",
        choices=list(encoding.MODELS),
        metavar="MODEL",
        help="the encodings compared (default: all of them)",
    )
    q.add_argument(
        "--percentage",
        type=int,
        default=50,
        metavar="P",
        help="render size, percent of the scene's resolution (default: 50)",
    )


def _blend(q):
    _receivers(q)
    _out(q, "folder of the bake")
    q.add_argument(
        "--weights",
        nargs="+",
        type=weight,
        default=[],
        metavar="NAME=W",
        help=f"a light set's weight, W a number or R,G,B (0–{MAX_WEIGHT:g}; 1 = as baked, 0 = off) (default: none given: "
        "every set keeps the scene's weight, else 1)",
    )


def _uv_report(q):
    _receivers(q)
    q.add_argument(
        "--json",
        metavar="OUT.json",
        help="also write the report as a JSON document (finite numbers only; written even when a receiver "
        "lacks the UV layer, which it lists under missing_uv_layer) (default: none: print the report only)",
    )


def _export(q):
    _out(q, "folder of the bake")
    target = q.add_mutually_exclusive_group(required=True)
    target.add_argument(
        "--glb", metavar="OUT.glb", help="write one binary .glb file (no default: one of --glb, --gltf is required)"
    )
    target.add_argument(
        "--gltf",
        metavar="OUT.gltf",
        help="write OUT.gltf with OUT.bin beside it (no default: one of --glb, --gltf is required)",
    )


#: The commands in the help's order: (name, what it does, the function adding its options).
COMMANDS = (
    ("unwrap", "xatlas lightmap UVs for the receivers", _unwrap),
    ("bake", "trace, encode and write the lightmap files", _bake),
    (
        "stale",
        "list what changed since the last bake in the output folder (objects, lights, world, atlas layouts) "
        "and how many receivers bake --changed would re-trace; nothing is traced or written",
        _stale,
    ),
    ("encode", "re-encode a finished bake from its SH EXR (no tracing)", _encode),
    (
        "compare",
        "compare every encoding of a finished bake against Cycles from the scene camera (no tracing; the bake's "
        "files are not changed): bytes per texel, diffuse and specular error, a table and a contact sheet; a "
        f"progress line per step, Ctrl-C stops after the current render (exit code {EXIT_CANCELLED}, an earlier "
        "report kept)",
        _compare,
    ),
    ("blend", "write the blended state of the light sets into each atlas's lightmap (no tracing)", _blend),
    (
        "uv-report",
        "check the receivers' lightmap UVs before a bake, changing nothing: per atlas and object the texels "
        "per metre against the target (and the ratio), texels, and the problems the Problems view shows "
        "(texels shared by two charts, flipped and degenerate UV faces, too few texels); problems are "
        f"reported with exit code {EXIT_OK}, a receiver without the lightmap UV layer is an input error "
        f"({EXIT_INPUT})",
        _uv_report,
    ),
    (
        "export",
        "export the scene to glTF 2.0 with its baked lightmaps, as File > Export > glTF 2.0 does with the "
        "extension enabled (docs/gltf.md; no baking): every render-visible object, the receivers with their "
        "atlases' lightmaps",
        _export,
    ),
)
