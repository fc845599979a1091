"""The command line's options as this run's settings: `overridden` is the scene's HHD settings
with the options given laid over them, a read-only view (`bridge.settings.Overridden`) every
command reads; `scene.hhd` is written only for --save (`apply_options`).
"""

from __future__ import annotations

import bpy

from ..bridge import settings as bridge_settings
from ..core.errors import BakeError

#: Options that set the scene setting of their name as given, and those that set an enum setting.
PLAIN_OPTIONS = (
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
ENUM_OPTIONS = ("model", "direction", "ambient", "solve", "inward_faces")


def option_values(args) -> dict:
    """{scene setting: value} of the options given (not --preset), in the order the settings are
    set; BakeError for a --collection the .blend does not have."""
    values = {key: getattr(args, key) for key in PLAIN_OPTIONS if getattr(args, key, None) is not None}
    for key in ENUM_OPTIONS:
        value = getattr(args, key, None)
        if value is not None:
            values[key] = value.upper().replace("-", "_")
    if getattr(args, "collection", None):
        if args.collection not in bpy.data.collections:
            raise BakeError(f"no collection named '{args.collection}'")
        values["target"], values["target_collection"] = 'COLLECTION', bpy.data.collections[args.collection]
    return values


def overridden(scene, args) -> bridge_settings.Overridden:
    """The scene's HHD settings overridden by the command line's options for this run: a
    read-only view (`bridge.settings.Overridden`); `scene.hhd` is not written (`apply_options`
    does that for --save). --preset sets its knobs first, explicit options override them."""
    values = option_values(args)
    if getattr(args, "preset", None):
        values = bridge_settings.with_preset(args.preset, values)
    return bridge_settings.Overridden(scene.hhd, values)


def apply_options(settings, args) -> None:
    """--save: write the command line's options into the scene's settings `settings`
    (`scene.hhd`), so the saved .blend keeps this run's settings: the preset first (its update
    sets its knobs), then the explicit options, which override it (the same values `overridden`
    gives)."""
    if getattr(args, "preset", None):
        settings.preset = args.preset.upper()
    for key, value in option_values(args).items():
        setattr(settings, key, value)
