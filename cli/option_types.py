"""What the options take, checked against the scene settings they override: the argparse types
(each a range error quoting the setting's range from properties.py), the help's fragments read
from properties.py (defaults, ranges, the enum items' descriptions), and the checks argparse cannot
make (options in conflict, values above a soft maximum). No .blend is needed: the help works without.
"""

from __future__ import annotations

import argparse
import math

from ..core.light_sets import MAX_WEIGHT

#: The most worker threads --threads takes (Blender's own limit for Render > Performance > Threads).
MAX_THREADS = 1024


def thread_count(text: str) -> int:
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


def setting(name: str) -> dict:
    """The keywords properties.py declares scene setting `name` with (name, default, min, max,
    items, description), read from the class's annotation: no registration or .blend needed, so
    the help quotes the settings' real ranges and defaults."""
    from ..properties import HHDSettings

    return HHDSettings.__annotations__[name].keywords


def new_scene_value(name: str) -> str:
    """Setting `name`'s value in a new scene, as the command line would spell it."""
    value = setting(name)["default"]
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, str):
        return value.lower() if "items" in setting(name) else (value or "empty")
    return f"{value:g}"


def default(name: str, unit: str = "") -> str:
    """'default: the scene's <Label> setting, <value> in a new scene': an option left out keeps the
    .blend's own setting."""
    value = new_scene_value(name)
    return f"default: the scene's {setting(name)['name']} setting, {value}{unit} in a new scene"


def span(name: str, unit: str = "") -> str:
    """The range properties.py allows for setting `name`: '4–65536' or '≥ 0'."""
    keywords = setting(name)
    low, high = keywords.get("min"), keywords.get("max")
    if high is None:
        return f"≥ {low:g}{unit}"
    return f"{low:g}–{high:g}{unit}"


#: The largest value of an integer setting without a declared max (Blender stores a C int).
INT_MAX = 2**31 - 1


def ranged(name: str, kind: type = float, unit: str = ""):
    """argparse type of the option of numeric scene setting `name`: a finite number of `kind`
    within the setting's hard range (properties.py's min/max, for an int at most INT_MAX:
    Blender would clamp it silently, or fail), else a usage error quoting the range. Values
    above a soft maximum are taken (`soft_warnings`: the run warns)."""
    keywords = setting(name)
    low, high = keywords.get("min"), keywords.get("max")
    if kind is int and high is None:
        high = INT_MAX
    allowed = f"{low:g}–{high}{unit}" if kind is int else span(name, unit)
    what = "a whole number" if kind is int else "a number"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"invalid {kind.__name__} value: {text!r} (give {what}, {allowed})"
            ) from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number: give {what}, {allowed}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{value}{unit} is out of range: give {allowed}")
        return value

    parse.__name__ = kind.__name__
    return parse


def soft_warnings(args) -> list[str]:
    """One line per option above its setting's soft maximum (the panel's slider end): allowed, but
    rarely meant."""
    out = []
    for key, unit in (("texel_density", " per metre"), ("time_budget", " s")):
        value, soft = getattr(args, key, None), setting(key).get("soft_max")
        if value is not None and soft is not None and value > soft:
            option = "--" + key.replace("_", "-")
            out.append(f"{option} {value:g}{unit} is above the usual 0–{soft:g}{unit}: check it is meant")
    return out


#: Dask's address schemes that take HOST:PORT (docs/farm.md: tcp://, or tls:// with certificates).
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss")


def scheduler_problem(address: str) -> str | None:
    """Why `address` is not a Dask scheduler address SCHEME://HOST:PORT, or None. Checked before
    Dask sees it: Dask raises ValueError deep inside its client for such an address, and the
    half-made client then holds the process for 60 s at exit."""
    scheme, sep, rest = address.rpartition("://")
    if sep and scheme not in SCHEDULER_SCHEMES:
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


def scheduler(text: str) -> str:
    """argparse type of --scheduler."""
    problem = scheduler_problem(text.strip())
    if problem:
        raise argparse.ArgumentTypeError(f"invalid scheduler address {text!r}: {problem}")
    return text.strip()


def choice_help(name: str, choices) -> str:
    """'a: what a does; b: what b does' for the choices of enum setting `name` (its items' descriptions)."""
    described = {key.lower(): text for key, _label, text in setting(name)["items"]}
    return "; ".join(f"{c}: {described[c][:1].lower()}{described[c][1:]}" if c in described else c for c in choices)


def weight(text: str) -> tuple[str, tuple[float, ...]]:
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


def conflicts(args) -> str | None:
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
