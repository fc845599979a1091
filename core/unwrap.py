"""Lightmap UVs with xatlas: chart and pack meshes into one shared atlas or one per object. No bpy.

Input meshes are triangle lists in world space (metres), so texel density is per metre of the
object as it stands in the scene (object scale included; negative scale is fine: only lengths
and areas matter). Output UVs are per triangle corner in [0, 1]² of the object's atlas, with
texel centres at (i + 0.5)/width. xatlas keeps the input triangle order; triangles with zero
area get no chart (xatlas puts them at UV (0, 0)) and are skipped by the rasteriser.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from . import deps
from .errors import BakeError

MIN_RESOLUTION, MAX_RESOLUTION = 256, 8192
#: Pause after each xatlas generate() before the atlas may be destroyed (see `_pack`).
WORKER_SETTLE_SECONDS = 0.05
#: Objects below this many covered texels get a warning: too few to show any lighting detail.
FEW_TEXELS = 64


@dataclass
class UnwrapMesh:
    """name: object name (for messages); positions (V, 3) world space, metres; triangles (T, 3)
    vertex indices; resolution / texel_density: per-object overrides (None = the settings')."""
    name: str
    positions: np.ndarray
    triangles: np.ndarray
    resolution: int | None = None
    texel_density: float | None = None


@dataclass
class UnwrapSettings:
    """resolution: atlas size in texels (square), used when texel_density is None.
    texel_density: texels per metre; the atlas size is then chosen to fit (≤ MAX_RESOLUTION).
    padding: texels between charts (≥ 2 for bilinear filtering; 2^k more per mip level).
    per_object: one atlas per object instead of one shared atlas."""
    resolution: int = 1024
    texel_density: float | None = None
    padding: int = 4
    per_object: bool = False


@dataclass
class ObjectUV:
    """uv (T, 3, 2) float32 per triangle corner in [0, 1]² of atlas `atlas`; texels: texels its
    charts cover (UV area × width × height); rect: (x0, y0, x1, y1) texel bounds in the atlas."""
    name: str
    uv: np.ndarray
    atlas: int
    texels: float
    rect: tuple
    charts: int


@dataclass
class UnwrapResult:
    objects: list[ObjectUV]
    atlas_sizes: list[tuple[int, int]]      # (width, height) per atlas
    utilisation: list[float]               # fraction of each atlas covered by charts
    charts: int
    warnings: list[str] = field(default_factory=list)


def padding_for_mips(mip_levels: int, base: int = 2) -> int:
    """Padding (texels) keeping charts apart down to the given mip level: base · 2^levels."""
    return base * (1 << max(0, mip_levels))


def validate(mesh: UnwrapMesh) -> None:
    """Raise BakeError naming the object if its geometry cannot be unwrapped."""
    p = np.asarray(mesh.positions)
    t = np.asarray(mesh.triangles)
    if t.size == 0:
        raise BakeError(f"'{mesh.name}' has no faces to unwrap")
    if not np.isfinite(p).all():
        raise BakeError(f"'{mesh.name}' has NaN or infinite vertex coordinates")
    if t.min() < 0 or t.max() >= len(p):
        raise BakeError(f"'{mesh.name}' has faces that reference missing vertices")
    if not (triangle_areas(p, t) > 0).any():
        raise BakeError(f"'{mesh.name}' has only zero-area faces: nothing to bake")


def triangle_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area `(T,)` of each triangle (same units as positions, squared)."""
    p = np.asarray(positions, dtype=np.float64)[np.asarray(triangles)]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def unwrap(meshes: list[UnwrapMesh], settings: UnwrapSettings,
           progress: Callable[[float, str], None] | None = None) -> UnwrapResult:
    """Chart and pack `meshes`: one shared atlas, or one per object when settings.per_object or
    an object overrides resolution/density (overridden objects get their own atlas)."""
    for m in meshes:
        validate(m)
    groups = _group(meshes, settings)
    objects, sizes, utilisation, warnings, charts = [None] * len(meshes), [], [], [], 0
    for gi, (indices, resolution, density) in enumerate(groups):
        if progress:
            progress(gi / len(groups), f"xatlas: atlas {gi + 1} of {len(groups)}")
        atlas, w, h = _pack([meshes[i] for i in indices], resolution, density, settings.padding)
        atlas_index = len(sizes)
        sizes.append((w, h))
        utilisation.append(float(np.mean(atlas.utilization)) if np.ndim(atlas.utilization) else float(atlas.utilization))
        charts += atlas.chart_count
        for k, i in enumerate(indices):
            objects[i] = _object_uv(meshes[i], atlas, k, atlas_index, w, h)
    for o in objects:
        if o.texels < FEW_TEXELS:
            warnings.append(f"'{o.name}' gets only {o.texels:.0f} lightmap texels: raise the resolution "
                            "or its texel density to see lighting detail on it")
    if progress:
        progress(1.0, "xatlas: done")
    return UnwrapResult(objects, sizes, utilisation, charts, warnings)


def _group(meshes, settings):
    """[(mesh indices, resolution, density)] per atlas to build."""
    shared = [i for i, m in enumerate(meshes)
              if not settings.per_object and m.resolution is None and m.texel_density is None]
    groups = [(shared, settings.resolution, settings.texel_density)] if shared else []
    for i, m in enumerate(meshes):
        if i not in shared:
            groups.append(([i], m.resolution or settings.resolution,
                           m.texel_density if m.texel_density is not None else
                           (None if m.resolution is not None else settings.texel_density)))
    return groups


def _pack(meshes, resolution, density, padding):
    """Run xatlas; return (atlas, width, height) with everything in a single atlas."""
    xatlas = deps.require("xatlas")
    if density is None and not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        raise BakeError(f"lightmap resolution {resolution} is outside {MIN_RESOLUTION}–{MAX_RESOLUTION}")
    if density is not None and not density > 0:
        raise BakeError(f"texel density must be positive, got {density}")

    def attempt(texels_per_unit, fixed_resolution):
        atlas = xatlas.Atlas()
        for m in meshes:
            atlas.add_mesh(np.ascontiguousarray(m.positions, dtype=np.float32),
                           np.ascontiguousarray(m.triangles, dtype=np.uint32))
        pack = xatlas.PackOptions()
        pack.padding = int(padding)
        pack.bilinear = True
        pack.texels_per_unit = float(texels_per_unit)
        pack.resolution = int(fixed_resolution)
        atlas.generate(pack_options=pack)
        # xatlas's TaskScheduler destructor wakes its workers without taking their mutex: a
        # worker still going idle after generate() can miss that wake-up, and Destroy then
        # joins it forever (seen once in CI: the process hung in ~TaskScheduler). Workers are
        # idle within microseconds; letting them settle before the atlas can be released
        # closes that window (≈ 3-6 generate() calls per unwrap, so well under a second).
        time.sleep(WORKER_SETTLE_SECONDS)
        return atlas

    if density is not None:
        atlas = attempt(density, 0)
        if max(atlas.width, atlas.height) > MAX_RESOLUTION or atlas.atlas_count > 1:
            raise BakeError(f"texel density {density:g}/m needs an atlas larger than {MAX_RESOLUTION}²: "
                            "lower the density or split the objects into several atlases")
        return atlas, atlas.width, atlas.height
    # Fixed resolution: let xatlas estimate the density, then shrink it by the measured overshoot
    # until one atlas of exactly resolution² holds every chart. Each retry re-runs xatlas (its
    # Python binding cannot re-pack alone), so scale by the overshoot: usually one retry.
    atlas = attempt(0, resolution)
    tpu = atlas.texels_per_unit
    for _ in range(12):
        if atlas.atlas_count == 1 and atlas.width <= resolution and atlas.height <= resolution:
            return atlas, resolution, resolution
        overshoot = max(atlas.width, atlas.height) / resolution if atlas.atlas_count == 1 else 1.0
        tpu *= min(0.97, 0.98 / max(overshoot, 1e-9))
        atlas = attempt(tpu, resolution)
    raise BakeError(f"could not pack the charts into one {resolution}² atlas")


def _object_uv(mesh, atlas, k, atlas_index, w, h):
    vmapping, indices, uvs = atlas[k]
    # xatlas normalises UVs by its own width/height; rescale to the final atlas size.
    scale = np.array([atlas.width / w, atlas.height / h], dtype=np.float64)
    uv = (uvs[indices] * scale).astype(np.float32)                      # (T, 3, 2)
    areas = 0.5 * np.abs(np.cross(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0])) * w * h
    live = areas > 0
    if live.any():
        px = uv[live].reshape(-1, 2) * [w, h]
        rect = (int(np.floor(px[:, 0].min())), int(np.floor(px[:, 1].min())),
                int(np.ceil(px[:, 0].max())), int(np.ceil(px[:, 1].max())))
    else:
        rect = (0, 0, 0, 0)
    return ObjectUV(mesh.name, uv, atlas_index, float(areas.sum()), rect, int(atlas.get_mesh_chart_count(k)))
