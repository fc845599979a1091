"""The bpy side of light sets: the weights an artist set, and blending the baked atlases.

`core.light_sets` holds the sets, their files and the blend; here only what reads Blender: the
atlases of the selected objects and the scene's set weights (`scene.hhd.light_sets`).
"""

from __future__ import annotations

import os
from pathlib import Path

import bpy

from ..core import light_sets as core_sets
from ..core.errors import BakeError
from ..core.files.lightmap_files import AtlasFiles, read_sidecar
from . import bake_session


def scene_weights(settings) -> dict[str, tuple[float, float, float]]:
    """{set: RGB weight} of the scene's light sets panel (`scene.hhd.light_sets`), if it has one."""
    return {item.name: tuple(item.weight) for item in getattr(settings, "light_sets", [])}


def weight_path(name: str) -> str:
    """RNA path, from the scene, of light set `name`'s weight: what the live blend's View Layer
    Attribute nodes read (keyed by name, so it survives reordering of the list)."""
    return f'hhd.light_sets["{bpy.utils.escape_identifier(name)}"].weight'


def sync_light_sets(scene, names) -> list[str]:
    """Make `scene.hhd.light_sets` list every set of `names` (a bake's, from its sidecar): missing
    sets are appended at weight 1, existing ones keep their weight (and keyframes). Sets no longer
    baked are kept, never removed or reordered: keyframes address the items by index
    (`hhd.light_sets[i].weight`), so removing one would move the animation onto another set.
    Returns the names added."""
    items = scene.hhd.light_sets
    added = [name for name in dict.fromkeys(names) if name not in items]
    for name in added:
        item = items.add()
        item.name = name
        item.weight = (1.0, 1.0, 1.0)
    return added


def baked_atlases(objects, settings, out_dir: str | None = None) -> list[AtlasFiles]:
    """The files of the atlases of `objects` in the output folder that were baked with light sets."""
    if not objects:
        raise BakeError("no mesh objects: select baked objects")
    folder = Path(bake_session.output_folder(settings, out_dir))
    groups, _ = bake_session.atlas_groups(objects, settings)
    out = []
    for name, *_ in groups:
        files = AtlasFiles(folder, name)
        if files.sidecar.is_file() and read_sidecar(files.sidecar).get("light_sets"):
            out.append(files)
    if not out:
        raise BakeError(
            f"no atlas of the selected objects in {folder} was baked with light sets: "
            "put lights or emissive objects in Light Groups (Object Properties > Shading) and bake"
        )
    return out


def scene_atlases(scene) -> list[AtlasFiles]:
    """The atlases of the scene's mesh objects (`object.hhd.atlas`, else the default atlas) that
    were baked with light sets into the output folder, sorted by name."""
    folder = Path(bake_session.output_folder(scene.hhd))
    names = {obj.hhd.atlas or bake_session.DEFAULT_ATLAS for obj in scene.objects if obj.type == 'MESH'}
    names.add(bake_session.DEFAULT_ATLAS)
    found = [AtlasFiles(folder, name) for name in sorted(names)]
    return [f for f in found if f.sidecar.is_file() and read_sidecar(f.sidecar).get("light_sets")]


def atlas_sets(atlases: list[AtlasFiles]) -> list[str]:
    """The light sets of `atlases`, in order, each once."""
    names: dict[str, None] = {}
    for files in atlases:
        names.update((entry["name"], None) for entry in read_sidecar(files.sidecar).get("light_sets", []))
    return list(names)


def blend_objects(objects, settings, weights: dict | None = None, out_dir: str | None = None) -> str:
    """Blend the light sets of every baked atlas of `objects` (see `blend_atlases`)."""
    return blend_atlases(baked_atlases(objects, settings, out_dir), settings, weights)


def blend_atlases(atlases: list[AtlasFiles], settings, weights: dict | None = None) -> str:
    """Write the blended state of the light sets into the lightmap of each of `atlases`
    (`core.light_sets.blend_atlas`) and reload its images; `weights` {set: number or RGB}
    override the scene's (`scene.hhd.light_sets`; sets in neither weigh 1). Raises BakeError
    for a weight of a set no atlas has. Returns a summary line."""
    if not atlases:
        raise BakeError("no atlas was baked with light sets: put lights in Light Groups and bake")
    baked = set(atlas_sets(atlases))
    unknown = sorted(set(weights or {}) - baked)
    if unknown:
        raise BakeError(
            f"no light set {', '.join(map(repr, unknown))} in the bake: its sets are {', '.join(map(repr, sorted(baked)))}"
        )
    chosen = {**scene_weights(settings), **(weights or {})}
    done = []
    for files in atlases:
        names = atlas_sets([files])
        record = core_sets.blend_atlas(files, {k: v for k, v in chosen.items() if k in names})
        bake_session.load_atlas_images(files, settings.pack_images)
        _reload_images(files.preview)
        shown = ", ".join(f"{k}={_format(v)}" for k, v in record["weights"].items())
        done.append(f"'{files.name}' ({shown})")
    return f"Blended light sets: {'; '.join(done)}"


def _reload_images(folder: Path) -> None:
    """Reload the loaded images whose files lie in `folder` (an atlas's preview images)."""
    folder_text = os.path.normpath(str(folder))
    for image in bpy.data.images:
        if image.filepath and os.path.dirname(os.path.normpath(bpy.path.abspath(image.filepath))) == folder_text:
            image.reload()


def _format(rgb) -> str:
    r, g, b = rgb
    return f"{r:g}" if r == g == b else f"{r:g},{g:g},{b:g}"
