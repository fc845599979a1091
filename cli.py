"""Headless use: `blender -b scene.blend --command hhd_lightmapper <unwrap|bake|encode|blend|uv-report|export> [options]`.

Registered with `bpy.utils.register_cli_command` when the extension is enabled. The same entry
point works with the `bpy` module from Python, without a Blender executable:

    python -m hhd_lightmapper.cli scene.blend bake --out lightmaps

(`standalone` parses the command line, then opens the .blend and registers the add-on). `--help`,
at the top or after a command, lists every command and option without a .blend. Exit codes are
stable, so build scripts can tell failures apart: see EXIT_* below; every failure prints one line
saying why: the file or option, the problem and the fix (README: "Exit codes and what the bake
refuses").
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import traceback

if __name__ == "__main__":  # a Ctrl-C or SIGTERM while bpy and numpy load: exit 5 at once, not a broken import
    from hhd_lightmapper.core.console import exit_on_stop_signal

    exit_on_stop_signal(5, "hhd_lightmapper")  # EXIT_CANCELLED, COMMAND below

import bpy  # noqa: E402

from . import blender_compat  # noqa: E402
from .bridge import settings as bridge_settings  # noqa: E402
from .core import encoding, presets  # noqa: E402
from .core.errors import BakeError, DependencyMissing, FullBakeNeeded  # noqa: E402
from .core.light_sets import MAX_WEIGHT  # noqa: E402
from .core.tracer import BakeCancelled  # noqa: E402

COMMAND = "hhd_lightmapper"
EXIT_OK = 0
EXIT_INPUT = 1  # the scene or the options cannot be baked as given (message names what)
EXIT_USAGE = 2  # bad command line (argparse)
EXIT_DEPENDENCY = 3  # a compiled package (embreex, xatlas, OpenEXR), or Dask for --scheduler, is missing
EXIT_OUTPUT = 4  # the output files could not be written (previous files are intact)
EXIT_CANCELLED = 5  # interrupted (Ctrl-C, SIGTERM): no file replaced
EXIT_FULL_BAKE = 6  # bake --only/--changed cannot go into the last bake's files (none, re-unwrapped): bake all
EXIT_INTERNAL = 70  # a bug: the traceback is printed

#: The most worker threads --threads takes (Blender's own limit for Render > Performance > Threads).
MAX_THREADS = 1024


def _thread_count(text: str) -> int:
    """argparse type of --threads: a whole number 0–MAX_THREADS (0 = every core)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"invalid thread count {text!r}: give a whole number 0–{MAX_THREADS} (0 = all cores)"
        ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"invalid thread count {value}: it must be ≥ 0 (0 = all cores)")
    if value > MAX_THREADS:
        raise argparse.ArgumentTypeError(
            f"invalid thread count {value}: it must be ≤ {MAX_THREADS} (0 = all cores, the usual choice)"
        )
    return value


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


def _setting(name: str) -> dict:
    """The keywords properties.py declares scene setting `name` with (name, default, min, max,
    items, description), read from the class's annotation: no registration or .blend needed, so
    the help quotes the settings' real ranges and defaults."""
    from .properties import HHDSettings

    return HHDSettings.__annotations__[name].keywords


def _new_scene_value(name: str) -> str:
    """Setting `name`'s value in a new scene, as the command line would spell it."""
    value = _setting(name)["default"]
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, str):
        return value.lower() if "items" in _setting(name) else (value or "empty")
    return f"{value:g}"


def _default(name: str, unit: str = "") -> str:
    """'default: the scene's <Label> setting, <value> in a new scene': an option left out keeps the
    .blend's own setting."""
    value = _new_scene_value(name)
    return f"default: the scene's {_setting(name)['name']} setting, {value}{unit} in a new scene"


def _span(name: str, unit: str = "") -> str:
    """The range properties.py allows for setting `name`: '4–65536' or '≥ 0'."""
    keywords = _setting(name)
    low, high = keywords.get("min"), keywords.get("max")
    if high is None:
        return f"≥ {low:g}{unit}"
    return f"{low:g}–{high:g}{unit}"


#: The largest value of an integer setting without a declared max (Blender stores a C int).
INT_MAX = 2**31 - 1


def _ranged(name: str, kind: type = float, unit: str = ""):
    """argparse type of the option of numeric scene setting `name`: a finite number of `kind`
    within the setting's hard range (properties.py's min/max, for an int at most INT_MAX:
    Blender would clamp it silently, or fail), else a usage error quoting the range. Values
    above a soft maximum are taken (_run warns)."""
    keywords = _setting(name)
    low, high = keywords.get("min"), keywords.get("max")
    if kind is int and high is None:
        high = INT_MAX
    span = f"{low:g}–{high}{unit}" if kind is int else _span(name, unit)
    what = "a whole number" if kind is int else "a number"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {kind.__name__} value: {text!r} (give {what}, {span})") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number: give {what}, {span}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{value}{unit} is out of range: give {span}")
        return value

    parse.__name__ = kind.__name__
    return parse


def _soft_warnings(args) -> list[str]:
    """One line per option above its setting's soft maximum (the panel's slider end): allowed, but
    rarely meant."""
    out = []
    for key, unit in (("texel_density", " per metre"), ("time_budget", " s")):
        value, soft = getattr(args, key, None), _setting(key).get("soft_max")
        if value is not None and soft is not None and value > soft:
            option = "--" + key.replace("_", "-")
            out.append(f"{option} {value:g}{unit} is above the usual 0–{soft:g}{unit}: check it is meant")
    return out


#: Dask's address schemes that take HOST:PORT (docs/farm.md: tcp://, or tls:// with certificates).
_SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss")


def _scheduler_problem(address: str) -> str | None:
    """Why `address` is not a Dask scheduler address SCHEME://HOST:PORT, or None. Checked before
    Dask sees it: Dask raises ValueError deep inside its client for such an address, and the
    half-made client then holds the process for 60 s at exit."""
    scheme, sep, rest = address.rpartition("://")
    if sep and scheme not in _SCHEDULER_SCHEMES:
        return f"unknown protocol '{scheme}://' (use tcp://HOST:PORT, or tls:// with certificates)"
    if rest.startswith("[") and "]" not in rest:
        return "an IPv6 host goes in brackets: tcp://[::1]:8786"
    host, colon, port = rest.rpartition(":")
    if not colon or not host or not port:
        return "no port: give tcp://HOST:PORT (a Dask scheduler listens on 8786 by default)"
    if host.startswith("[") != host.endswith("]") or (":" in host and not host.startswith("[")):
        return "an IPv6 host goes in brackets: tcp://[::1]:8786"
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        return f"port '{port}' is not a number 1–65535"
    return None


def _scheduler(text: str) -> str:
    """argparse type of --scheduler."""
    problem = _scheduler_problem(text.strip())
    if problem:
        raise argparse.ArgumentTypeError(f"invalid scheduler address {text!r}: {problem}")
    return text.strip()


def _choices(name: str, choices) -> str:
    """'a: what a does; b: what b does' for the choices of enum setting `name` (its items' descriptions)."""
    described = {key.lower(): text for key, _label, text in _setting(name)["items"]}
    return "; ".join(f"{c}: {described[c][:1].lower()}{described[c][1:]}" if c in described else c for c in choices)


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's and epilog's lines (the calling forms, the exit-code table) as
    written; option help is wrapped as usual, but never inside a hyphenated word such as an
    option's name (--noise-target)."""

    def _split_lines(self, text, width):
        import textwrap

        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)


def _parser(prog: str = BLENDER_PROG) -> argparse.ArgumentParser:
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

    def command(name: str, text: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=text, description=text, epilog=exit_codes, formatter_class=_HelpFormatter)

    def receivers(q):
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

    def threads(q):
        q.add_argument(
            "--threads",
            type=_thread_count,
            default=None,
            metavar="N",
            help=f"worker threads, 0–{MAX_THREADS}; 0 = every core this process may use (default: the scene's "
            "Render > Performance > Threads, as a headless Cycles render; Auto = every core)",
        )

    def encoder(q):
        q.add_argument(
            "--model",
            choices=list(encoding.MODELS),
            help=f"the encoding written: {_choices('model', encoding.MODELS)} ({_default('model')})",
        )
        q.add_argument(
            "--solve",
            choices=list(encoding.SOLVES),
            help=f"how an SG encoding fits its lobes: {_choices('solve', encoding.SOLVES)} ({_default('solve')})",
        )
        q.add_argument(
            "--direction",
            choices=list(encoding.DIRECTIONS),
            help=f"how the highlight direction is found: {_choices('direction', encoding.DIRECTIONS)} "
            f"({_default('direction')})",
        )
        q.add_argument(
            "--ambient",
            choices=list(encoding.AMBIENTS),
            help=f"ambient weight: {_choices('ambient', encoding.AMBIENTS)} ({_default('ambient')})",
        )
        q.add_argument(
            "--phi-search",
            action="store_true",
            default=None,
            help="also search the highlight direction's azimuth (slower, slightly lower error) "
            f"({_default('phi_search')})",
        )

    def denoise(q, what, default):
        q.add_argument(
            "--denoise",
            action=argparse.BooleanOptionalAction,
            default=None,
            help=f"{what} the SH denoised with Open Image Denoise's lightmap filter (Blender's own "
            f"library), or not (default: {default}, {_new_scene_value('denoise')} in a new scene); the SH "
            "EXR always keeps the SH as traced",
        )

    def stitch(q, what):
        q.add_argument(
            "--stitch",
            dest="stitch_seams",
            action=argparse.BooleanOptionalAction,
            default=None,
            help=f"{what} the SH stitched along the UV seams of smooth surfaces, so no line shows where a "
            f"surface is split between charts, or not ({_default('stitch_seams')})",
        )

    def out(q, what):
        q.add_argument(
            "--out",
            metavar="DIR",
            help=f"{what}; // at the start = relative to the .blend ({_default('output_dir')})",
        )

    def resolution(q, what):
        q.add_argument(
            "--resolution",
            type=_ranged("resolution", int),
            metavar="TEXELS",
            help=f"atlas width and height in texels, {_span('resolution')}: {what} ({_default('resolution')})",
        )

    def texel_density(q, what):
        q.add_argument(
            "--texel-density",
            type=_ranged("texel_density"),
            metavar="PER_METRE",
            help=f"texels per metre, {_span('texel_density')}, {what}; 0 = use --resolution instead (only "
            "one of the two may be given) "
            f"({_default('texel_density')})",
        )

    q = command("unwrap", "xatlas lightmap UVs for the receivers")
    receivers(q)
    resolution(q, "the size of every atlas when the texel density is 0")
    texel_density(q, "sizing each atlas to its surface area")
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

    q = command("bake", "trace, encode and write the lightmap files")
    receivers(q)
    encoder(q)
    out(q, "output folder")
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
    q.add_argument(
        "--samples",
        type=_ranged("samples", int),
        metavar="N",
        help=f"hemisphere samples per texel (the most a texel takes with --noise-target), {_span('samples')} "
        f"({_default('samples')})",
    )
    q.add_argument(
        "--bounces",
        type=_ranged("bounces", int),
        metavar="N",
        help=f"diffuse interreflection bounces after the first hit, {_span('bounces')} ({_default('bounces')})",
    )
    q.add_argument(
        "--noise-target",
        type=_ranged("noise_target"),
        metavar="PERCENT",
        help="stop a texel once the standard error of its irradiance is below PERCENT of it, "
        f"{_span('noise_target')}; 0 = every texel takes every sample ({_default('noise_target')})",
    )
    q.add_argument(
        "--time-budget",
        type=_ranged("time_budget", unit=" s"),
        metavar="SECONDS",
        help=f"stop tracing after SECONDS, {_span('time_budget')} (the first pass always completes); "
        f"0 = no limit ({_default('time_budget', ' s')})",
    )
    q.add_argument(
        "--seed",
        type=_ranged("seed", int),
        metavar="N",
        help=f"random seed, {_span('seed')}: the same seed gives the same bake ({_default('seed')})",
    )
    denoise(q, "encode", "the --preset's, else the scene's Denoise setting")
    stitch(q, "encode")
    q.add_argument(
        "--inward-faces",
        choices=["open-side", "as-modelled", "refuse"],
        help="faces whose normals point into their own closed object (an inside-out mesh): open-side "
        "bakes them on the side light reaches (n_v turned round, as Cycles shades them), as-modelled "
        f"bakes them as they are (black there) with a warning, refuse exits with code {EXIT_INPUT} naming "
        "them; a closed object holding a light is a room seen from inside and left alone "
        f"({_default('inward_faces')})",
    )
    q.add_argument(
        "--unwrap",
        action="store_true",
        help="unwrap the receivers first, as the unwrap command does (linked duplicates and collection instances "
        "become instances) "
        "(default: off: bake the lightmap UVs the objects have)",
    )
    resolution(
        q,
        "for --unwrap when the texel density is 0, and the atlas size of receivers whose lightmap UVs "
        "were not made by this add-on's unwrap",
    )
    texel_density(q, "for --unwrap")
    q.add_argument(
        "--save",
        action="store_true",
        help="save the .blend afterwards, keeping the loaded images and this run's settings (default: off)",
    )
    q.add_argument(
        "--scheduler",
        type=_scheduler,
        metavar="tcp://HOST:PORT",
        help="trace on the Dask cluster of this scheduler (docs/farm.md): the same files as a local bake; "
        "finished tasks are kept in the output folder's .hhd_farm, so the same command resumes "
        "(default: the scene's Dask Scheduler setting; empty, as in a new scene: bake on this machine)",
    )
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
    threads(q)

    q = command(
        "stale",
        "list what changed since the last bake in the output folder (objects, lights, world, atlas layouts) "
        "and how many receivers bake --changed would re-trace; nothing is traced or written",
    )
    out(q, "folder of the bake")

    q = command("encode", "re-encode a finished bake from its SH EXR (no tracing)")
    receivers(q)
    encoder(q)
    out(q, "folder of the bake")
    denoise(q, "re-encode", "the scene's Denoise setting")
    stitch(q, "re-encode")
    threads(q)

    q = command(
        "compare",
        "compare every encoding of a finished bake against Cycles from the scene camera (no tracing; the bake's "
        "files are not changed): bytes per texel, diffuse and specular error, a table and a contact sheet; a "
        f"progress line per step, Ctrl-C stops after the current render (exit code {EXIT_CANCELLED}, an earlier "
        "report kept)",
    )
    receivers(q)
    out(q, "folder of the bake")
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

    q = command("blend", "write the blended state of the light sets into each atlas's lightmap (no tracing)")
    receivers(q)
    out(q, "folder of the bake")
    q.add_argument(
        "--weights",
        nargs="+",
        type=_weight,
        default=[],
        metavar="NAME=W",
        help=f"a light set's weight, W a number or R,G,B (0–{MAX_WEIGHT:g}; 1 = as baked, 0 = off) (default: none given: "
        "every set keeps the scene's weight, else 1)",
    )
    q = command(
        "uv-report",
        "check the receivers' lightmap UVs before a bake, changing nothing: per atlas and object the texels "
        "per metre against the target (and the ratio), texels, and the problems the Problems view shows "
        "(texels shared by two charts, flipped and degenerate UV faces, too few texels); problems are "
        f"reported with exit code {EXIT_OK}, a receiver without the lightmap UV layer is an input error "
        f"({EXIT_INPUT})",
    )
    receivers(q)
    q.add_argument(
        "--json",
        metavar="OUT.json",
        help="also write the report as a JSON document (finite numbers only; written even when a receiver "
        "lacks the UV layer, which it lists under missing_uv_layer) (default: none: print the report only)",
    )

    q = command(
        "export",
        "export the scene to glTF 2.0 with its baked lightmaps, as File > Export > glTF 2.0 does with the "
        "extension enabled (docs/gltf.md; no baking): every render-visible object, the receivers with their "
        "atlases' lightmaps",
    )
    out(q, "folder of the bake")
    target = q.add_mutually_exclusive_group(required=True)
    target.add_argument(
        "--glb", metavar="OUT.glb", help="write one binary .glb file (no default: one of --glb, --gltf is required)"
    )
    target.add_argument(
        "--gltf",
        metavar="OUT.gltf",
        help="write OUT.gltf with OUT.bin beside it (no default: one of --glb, --gltf is required)",
    )
    return p


def _weight(text: str) -> tuple[str, tuple[float, ...]]:
    """'NAME=W' or 'NAME=R,G,B' -> (NAME, weight), each number finite and 0–MAX_WEIGHT."""
    name, sep, value = text.partition("=")
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        parts = ()
    if not sep or not name or len(parts) not in (1, 3):
        raise argparse.ArgumentTypeError(f"expected NAME=W or NAME=R,G,B, got '{text}'")
    if not all(math.isfinite(v) and 0.0 <= v <= MAX_WEIGHT for v in parts):
        raise argparse.ArgumentTypeError(
            f"light set '{name}': weight '{value}' is out of range: give 0–{MAX_WEIGHT:g} per channel "
            "(1 = as baked, 0 = off)"
        )
    return name, parts if len(parts) == 3 else parts * 3


def _conflicts(args) -> str | None:
    """Options that contradict each other (argparse cannot see it), or None."""
    if getattr(args, "objects", None) and getattr(args, "collection", None):
        return "--objects and --collection both name the receivers: give one of them"
    subset = getattr(args, "only", None) or getattr(args, "changed", False)
    if getattr(args, "influenced", False) and not getattr(args, "changed", False):
        return "--influenced widens --changed: give --changed --influenced"
    if getattr(args, "only", None) and getattr(args, "changed", False):
        return "--only and --changed both choose the receivers to re-trace: give one of them"
    for other in ("objects", "collection", "unwrap", "scheduler"):
        if subset and getattr(args, other, None):
            return (
                f"--{other} with --only/--changed: a partial bake re-traces receivers of the last bake, into its "
                "layout, on this machine"
            )
    density = getattr(args, "texel_density", None)
    if density and getattr(args, "resolution", None) is not None:
        return (
            f"--texel-density {density:g} and --resolution {args.resolution} both size the atlas: give one "
            "(--texel-density 0 --resolution N to switch a density-sized scene to a fixed size)"
        )
    return None


#: Options that set the scene setting of their name as given, and those that set an enum setting.
_PLAIN_OPTIONS = (
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
)
_ENUM_OPTIONS = ("model", "direction", "ambient", "solve", "inward_faces")


def _option_values(args) -> dict:
    """{scene setting: value} of the options given (not --preset), in the order the settings are
    set; BakeError for a --collection the .blend does not have."""
    values = {key: getattr(args, key) for key in _PLAIN_OPTIONS if getattr(args, key, None) is not None}
    for key in _ENUM_OPTIONS:
        value = getattr(args, key, None)
        if value is not None:
            values[key] = value.upper().replace("-", "_")
    if getattr(args, "collection", None):
        if args.collection not in bpy.data.collections:
            raise BakeError(f"no collection named '{args.collection}'")
        values["target"], values["target_collection"] = 'COLLECTION', bpy.data.collections[args.collection]
    return values


def _settings(scene, args) -> bridge_settings.Overridden:
    """The scene's HHD settings overridden by the command line's options for this run: a
    read-only view (`bridge.settings.Overridden`); `scene.hhd` is not written (`_apply_options`
    does that for --save). --preset sets its knobs first, explicit options override them."""
    values = _option_values(args)
    if getattr(args, "preset", None):
        values = bridge_settings.with_preset(args.preset, values)
    return bridge_settings.Overridden(scene.hhd, values)


def _apply_options(settings, args) -> None:
    """--save: write the command line's options into the scene's settings `settings`
    (`scene.hhd`), so the saved .blend keeps this run's settings: the preset first (its update
    sets its knobs), then the explicit options, which override it (the same values `_settings`
    gives)."""
    if getattr(args, "preset", None):
        settings.preset = args.preset.upper()
    for key, value in _option_values(args).items():
        setattr(settings, key, value)


def _unwrap(context, args, settings) -> str:
    """Unwrap the receivers with a progress line; Ctrl-C cancels (BakeCancelled, no mesh changed).
    A texel density no atlas can hold is refused before xatlas runs (`core.unwrap.atlas_limits`, in the
    core unwrap)."""
    from .bridge import bake_session
    from .core.console import ConsoleProgress, interrupt_as_cancel
    from .operators import unwrap

    objects = bake_session.target_objects(context, args.objects, settings)
    if not objects:
        raise BakeError("no receivers: pass --objects or --collection, or save the .blend with them selected")
    job = unwrap.read_objects(objects, settings, getattr(args, "make_single_user", False))
    print(f"unwrap: {len(objects)} object(s)", flush=True)
    progress = ConsoleProgress()
    try:
        with interrupt_as_cancel() as cancel:
            result = unwrap.compute(job, progress, cancel)
    finally:
        progress.close()
    summary, warnings = unwrap.write_objects(job, settings, result)
    for w in warnings:
        print(f"warning: {w}")
    return summary


def _bake(context, args, settings) -> str:
    from .bridge import bake_session
    from .core.console import ConsoleProgress, interrupt_as_cancel

    if args.only or args.changed:
        return _bake_subset(context, args, settings)
    if args.unwrap:
        print(_unwrap(context, args, settings), flush=True)
    session = bake_session.BakeSession(context, args.objects, args.out, threads=args.threads, settings=settings)
    for w in session.warnings:
        print(f"warning: {w}")
    print(f"bake: {session.describe()}", flush=True)
    address = args.scheduler or session.scheduler.strip()  # the option, else the scene's Dask Scheduler
    if address and not args.scheduler and _scheduler_problem(address):
        raise BakeError(
            f"the scene's Dask Scheduler setting {address!r} is not a scheduler address: "
            f"{_scheduler_problem(address)}; fix it (Render > HHD Lightmapper) or pass --scheduler"
        )
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


def _bake_subset(context, args, settings) -> str:
    """`bake --only NAMES` / `--changed [--influenced]`: `bridge.incremental_session`."""
    from .bridge import incremental_session
    from .core.console import ConsoleProgress, interrupt_as_cancel

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


def _stale(context, args, _view) -> str:
    """`stale`: what changed since the last bake (`bridge.incremental_session.stale_report`); it
    takes no option that overrides a scene setting (--out is its folder)."""
    from .bridge import incremental_session

    stale, lines = incremental_session.stale_report(context, args.out)
    for line in lines[:-1]:
        print(f"stale: {line}")
    return lines[-1]


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


def _uv_report(context, args, settings) -> str:
    """`uv-report`: the views' figures (`shaders.texel_views.report`), printed and with --json
    written; the .blend is not changed. Receivers without the lightmap UV layer: EXIT_INPUT,
    named, after the report of the others."""
    import json

    from .bridge import bake_session
    from .shaders import texel_views

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


def _export(context, args, _view) -> str:
    """`export`: Blender's glTF exporter with the HHD hook (bridge/gltf_export.py), as File > Export;
    the lightmaps from --out, else the scene's Output Folder."""
    from .bridge import gltf_export

    path = args.glb or args.gltf
    result = gltf_export.export(path, glb=bool(args.glb), out_dir=args.out)
    for w in result["warnings"]:
        print(f"warning: {w}")
    return f"{len(result['exported'])} object(s) with lightmaps -> {path}"


def _encode(context, args, settings) -> str:
    from .bridge import bake_session
    from .operators import encode

    objects = bake_session.target_objects(context, args.objects, settings)
    threads = bridge_settings.scene_threads(context.scene) if args.threads is None else args.threads
    summary, warnings = encode.reencode_objects(objects, settings, args.out, threads=threads)
    for w in warnings:
        print(f"warning: {w}")
    return summary


def _compare(context, args, settings) -> str:
    """`compare`: a progress line per step (each Cycles render, each atlas's post stages and
    encodings, the report); Ctrl-C or SIGTERM stops at the next step (within a denoise): no
    report file is replaced, the scene as it was (EXIT_CANCELLED)."""
    from .bridge import compare
    from .core.console import ConsoleProgress, interrupt_as_cancel

    if args.cycles_samples < 2 or not 1 <= args.percentage <= 100 or any(not 0.0 < r <= 1.0 for r in args.roughness):
        raise BakeError("compare: --cycles-samples ≥ 2, --percentage in 1–100 and --roughness in (0, 1]")
    job = compare.prepare(
        context,
        args.objects,
        args.out,
        args.report,
        samples=args.cycles_samples,
        roughness=tuple(args.roughness),
        models=tuple(args.models or compare.core_compare.MODELS),
        percentage=args.percentage,
        settings=settings,
    )
    print(f"compare: {len(job.steps)} steps into {job.report_dir}", flush=True)
    progress = ConsoleProgress(step=0.0)
    try:
        with interrupt_as_cancel() as cancel:
            summary, warnings = compare.run_steps(job, progress, cancel)
    finally:
        progress.close()
    for w in warnings:
        print(f"warning: {w}")
    return summary


def _blend(context, args, settings) -> str:
    from .bridge import bake_session, light_sets

    objects = bake_session.target_objects(context, args.objects, settings)
    return light_sets.blend_objects(objects, settings, dict(args.weights), args.out)


def main(argv: list[str]) -> int:
    """Run one command on the open .blend; returns the exit code (never raises). Blender's entry
    point (`blender -b FILE.blend --command hhd_lightmapper ...`): `--help` prints the help."""
    args = _parse(_parser(BLENDER_PROG), argv)
    return args if isinstance(args, int) else _run(args)


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The commands of `parser`, by name: its subparsers."""
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def _parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace | int:
    """The parsed command line, or the exit code once argparse has printed the help (EXIT_OK) or
    a usage error (EXIT_USAGE). No arguments at all print the full help, as a usage error."""
    if not argv:
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    try:
        args = parser.parse_args(argv)
        conflict = _conflicts(args)
        if conflict:
            _commands(parser)[args.action].error(conflict)  # usage line and message, SystemExit(2)
        return args
    except SystemExit as exc:
        return EXIT_USAGE if exc.code else EXIT_OK


class _OutputProblem(Exception):
    """The output folder or the .blend cannot be written: EXIT_OUTPUT with this message."""


def _output_problem(folder: str) -> str | None:
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


def _save_problem() -> str | None:
    """Why --save cannot save the open .blend, or None (checked before the command runs)."""
    path = bpy.data.filepath
    if not bpy.data.is_saved or not path:
        return None  # a BakeError (input) in _save
    if os.path.exists(path) and not os.access(path, os.W_OK):
        return f"--save: {path} is read-only: make it writable, or leave out --save (nothing was baked)"
    folder = os.path.dirname(path) or "."
    if not os.access(folder, os.W_OK | os.X_OK):
        return (
            f"--save: the folder {folder} is not writable (Blender saves through a temporary file there): "
            "make it writable, or leave out --save (nothing was baked)"
        )
    return None


def _save(args) -> None:
    """--save: the .blend, after the command (its files are already written)."""
    if not bpy.data.is_saved:
        raise BakeError("--save: the .blend has never been saved, so there is no file to save to")
    try:
        bpy.ops.wm.save_mainfile()
    except RuntimeError as exc:
        detail = " ".join(str(exc).replace("Error:", "").split())
        raise _OutputProblem(
            f"--save: cannot save {bpy.data.filepath}: {detail} (the {args.action}'s files were written; the "
            ".blend on disk is unchanged)"
        ) from None


def _check_before(context, args, settings) -> None:
    """What can be known to fail before any work: an unwritable output folder or .blend (--save);
    `settings`: this run's (`_settings`)."""
    from .bridge import bake_session

    if getattr(args, "save", False):
        if not bpy.data.is_saved:
            raise BakeError("--save: the .blend has never been saved, so there is no file to save to")
        problem = _save_problem()
        if problem:
            raise _OutputProblem(problem)
    # unwrap, uv-report and export write no bake files (--json, --glb are checked as they are written)
    if args.action not in ("unwrap", "uv-report", "export", "stale", "compare"):
        problem = _output_problem(bake_session.output_folder(settings, args.out))
        if problem:
            raise _OutputProblem(problem)


def _os_problem(exc: OSError) -> str:
    """One line for an OSError met while writing: the file (not its temporary) and the fix."""
    import errno

    from .core.files.exr import target_of

    name = target_of(exc.filename) if exc.filename else "the output"
    if exc.errno in (errno.EEXIST, errno.ENOTDIR):
        return f"cannot write {name}: a file stands where a folder is needed; give --out a folder path"
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"cannot write {name}: permission denied; choose another --out or make it writable"
    if exc.errno == errno.ENOSPC:
        return f"cannot write {name}: the disk is full; free some space and run again"
    return f"cannot write {name}: {exc.strerror or exc}"


def _run(args: argparse.Namespace) -> int:
    """Run the parsed command on the open .blend; returns the exit code (never raises). SIGTERM
    is Ctrl-C here: the files being written are deleted, none is replaced (EXIT_CANCELLED)."""
    from .core.console import terminate_as_interrupt

    context = bpy.context
    start = time.perf_counter()
    try:
        with terminate_as_interrupt():
            settings = _settings(context.scene, args)
            for w in _soft_warnings(args):
                print(f"warning: {w}", flush=True)
            _check_before(context, args, settings)
            commands = {
                "unwrap": _unwrap,
                "bake": _bake,
                "encode": _encode,
                "compare": _compare,
                "blend": _blend,
                "export": _export,
                "uv-report": _uv_report,
                "stale": _stale,
            }
            summary = commands[args.action](context, args, settings)
            if getattr(args, "save", False):
                _apply_options(context.scene.hhd, args)  # --save keeps this run's settings
                _save(args)
    except DependencyMissing as exc:
        return _fail(EXIT_DEPENDENCY, exc)
    except FullBakeNeeded as exc:
        return _fail(EXIT_FULL_BAKE, exc)
    except (BakeCancelled, KeyboardInterrupt):
        return _fail(EXIT_CANCELLED, "interrupted: no output file was replaced")
    except BakeError as exc:
        return _fail(EXIT_INPUT, exc)
    except _OutputProblem as exc:
        return _fail(EXIT_OUTPUT, exc)
    except OSError as exc:
        return _fail(EXIT_OUTPUT, f"{_os_problem(exc)} (previous files are intact)")
    except Exception:  # a bug: say so, with the traceback, and a distinct code
        traceback.print_exc()
        return _fail(EXIT_INTERNAL, "internal error (please report it with the traceback above)")
    print(f"{args.action}: {summary} [{time.perf_counter() - start:.1f} s]", flush=True)
    return EXIT_OK


def _fail(code: int, message) -> int:
    print(f"{COMMAND}: error: {message}", file=sys.stderr, flush=True)
    return code


def standalone(argv: list[str]) -> int:
    """`python -m hhd_lightmapper.cli FILE.blend <command> ...` under the bpy module. The command
    line is parsed before the .blend is opened: `--help` (with or without FILE.blend, at the top or
    after a command) and usage errors never open a file."""
    from .core.console import terminate_as_interrupt

    with terminate_as_interrupt():  # the start-up's handlers (exit_on_stop_signal) end here
        try:
            return _standalone(argv)
        except KeyboardInterrupt:  # while opening the .blend or registering: nothing written
            return _fail(EXIT_CANCELLED, "interrupted while starting: nothing was written")


def _standalone(argv: list[str]) -> int:
    parser = _parser(STANDALONE_PROG)
    has_blend = bool(argv) and argv[0].endswith(".blend")
    if argv and not has_blend and not argv[0].startswith("-") and argv[0] not in _commands(parser):
        parser.print_usage(sys.stderr)  # a file that is not a .blend, or a misspelt command
        return _fail(EXIT_USAGE, f"expected FILE.blend or a command first, got {argv[0]!r}")
    args = _parse(parser, argv[1:] if has_blend else argv)
    if isinstance(args, int):
        return args
    if not has_blend:
        parser.print_usage(sys.stderr)
        return _fail(EXIT_USAGE, "the first argument must be the .blend file to open (FILE.blend)")
    try:
        bpy.ops.wm.open_mainfile(filepath=argv[0])
    except RuntimeError as exc:
        return _fail(EXIT_INPUT, f"cannot open {argv[0]}: {exc}")
    import hhd_lightmapper

    hhd_lightmapper.register()
    try:
        return _run(args)
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
