"""Stage 1 of a bake's atlases: the Embree scene every stage of one bake shares, each atlas's
bake points (checked: every object covers a texel), and the faces that point into their own
object (`core.bakepoints.inward`), found and turned round before any bake point. No bpy."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import bakepoints, memory, progress
from ..bakepoints import BakePoints, inward
from ..errors import BakeError, InwardFacesRefused
from ..progress import Tick
from ..rays import RayScene
from ..scene import BakeScene
from .data import AtlasInput, _check_cancel


def points_of(
    atlas: AtlasInput, ray_scene: RayScene | None, threads: int = 0, cancel=None, tick: Tick | None = None
) -> BakePoints:
    """Stage 1 for one atlas: its bake points (buried and near-cover probes against `ray_scene`,
    all the scene's geometry). Raises BakeError naming an object whose UVs cover no texel.
    `threads`: workers of the probe passes (0 = every core). `tick`: the stage's part of the
    bake's progress (it checks for the cancel), else `cancel()` is polled."""
    points = bakepoints.build(
        atlas.surface,
        atlas.width,
        atlas.height,
        occluders=ray_scene,
        check=tick if tick is not None else lambda: _check_cancel(cancel),
        threads=threads,
        albedo=False,  # the tracer takes albedo from the scene's triangles
    )
    memory.trim_heap()  # what the probe threads freed (memory)
    return check_points(atlas, points)


def check_points(atlas: AtlasInput, points: BakePoints) -> BakePoints:
    """`points`, or BakeError naming an object of `atlas` whose UVs cover no texel."""
    counts = np.bincount(points.object_index, minlength=len(atlas.objects))
    empty = [atlas.objects[k] for k in np.unique(atlas.surface.object_index) if counts[k] == 0]
    if empty:
        raise BakeError(
            f"{', '.join(repr(n) for n in empty)}: the lightmap UVs cover no texel of "
            f"atlas '{atlas.name}' (zero-area UVs): run Unwrap again"
        )
    return points


def ray_scene_of(scene: BakeScene) -> RayScene | None:
    """The Embree scene every stage of one bake shares (bake-point probes, tracing); None for a
    scene without geometry. Its BVH builds on Embree's threads while the bake points rasterise."""
    return RayScene(scene.triangles) if len(scene.triangles) else None


def check_inward(
    atlases: list[AtlasInput], scene: BakeScene, mode: str = inward.OPEN_SIDE, check=None, threads: int = 0
) -> tuple[list[AtlasInput], list[list[inward.InwardObject]], BakeScene]:
    """Faces that point into their own object (`core.bakepoints.inward`), found before any bake point:
    (the atlases to bake: with `mode` OPEN_SIDE those faces' normals turned round, else as
    given; per atlas the objects found; the scene to trace: with OPEN_SIDE those faces' winding
    turned round, `inward.flip_scene`). REFUSE with any found: InwardFacesRefused naming them.
    `check`: called between objects (a `core.progress.Tick` is told how far the check has come);
    `threads`: workers over the objects (0 = every core)."""
    if mode not in inward.MODES:
        raise BakeError(f"inward faces: unknown setting {mode!r} (one of {', '.join(inward.MODES)})")
    lights = inward.light_points(scene)
    sizes = [max(len(atlas.surface.positions), 1) for atlas in atlases]
    ticks = progress.ticker(check).split(sizes)
    found = [inward.find(atlas.surface, atlas.objects, lights, tick, threads) for atlas, tick in zip(atlases, ticks)]
    if mode == inward.REFUSE and any(found):
        raise InwardFacesRefused([item.message(mode) for items in found for item in items])
    if mode == inward.OPEN_SIDE and any(found):
        flipped = [np.concatenate([x.triangles for x in f]) if f else np.zeros(0, np.int64) for f in found]
        positions = np.concatenate([a.surface.positions[rows] for a, rows in zip(atlases, flipped)])
        scene = inward.flip_scene(scene, positions)
        atlases = [replace(a, surface=inward.flip(a.surface, rows)) for a, rows in zip(atlases, flipped)]
    return atlases, found, scene


def _inward_sidecar(extra: dict, found: list[inward.InwardObject], mode: str) -> dict:
    """The sidecar's extra keys of one atlas: `extra`, plus (only when some of its objects have
    faces that point in) their messages in "notes" and their records in "inward_faces"."""
    if not found:
        return extra
    notes = list(extra.get("notes", [])) + [item.message(mode) for item in found]
    return {**extra, "notes": notes, "inward_faces": [item.note(mode) for item in found]}
