"""Lightmap UVs with xatlas: chart and pack meshes into one shared atlas or one per object. No bpy.

Input meshes are triangle lists in world space (metres), so texel density is per metre of the
object as it stands in the scene (object scale included; negative scale is fine: only lengths
and areas matter). Output UVs are per triangle corner in [0, 1]² of the object's atlas, with
texel centres at (i + 0.5)/width. xatlas keeps the input triangle order; triangles with zero
area get no chart (xatlas puts them at UV (0, 0)) and are skipped by the rasteriser. xatlas runs
in a child process (`xatlas_worker`), so a crash in its threads is a retry, not a lost session.
"""
from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from . import deps
from .errors import BakeError

MIN_RESOLUTION, MAX_RESOLUTION = 256, 8192
#: xatlas runs in a child process (`xatlas_worker`): tries before giving up, and the time after
#: which a child counts as hung (1M triangles take ≈ 140 s on 2 cores).
XATLAS_ATTEMPTS = 3
XATLAS_TIMEOUT_BASE, XATLAS_TIMEOUT_PER_TRIANGLE = 120.0, 1e-3
_WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xatlas_worker.py")
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
        atlas = _pack([meshes[i] for i in indices], resolution, density, settings.padding)
        # a density-driven atlas is xatlas's own size; a fixed one is resolution² (charts fit in it)
        w, h = (atlas["width"], atlas["height"]) if density is not None else (resolution, resolution)
        atlas_index = len(sizes)
        sizes.append((w, h))
        utilisation.append(atlas["utilisation"])
        charts += atlas["charts"]
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
    """Chart and pack `meshes` into one atlas with xatlas in a child process (see
    `xatlas_worker`); returns the worker's result dict. A crashed or hung child is retried."""
    deps.require("xatlas")          # a missing wheel is a clear message here, not in the child
    if density is None and not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        raise BakeError(f"lightmap resolution {resolution} is outside {MIN_RESOLUTION}–{MAX_RESOLUTION}")
    if density is not None and not density > 0:
        raise BakeError(f"texel density must be positive, got {density}")
    job = {"meshes": [(np.asarray(m.positions, dtype=np.float32), np.asarray(m.triangles, dtype=np.uint32))
                      for m in meshes],
           "resolution": int(resolution), "density": density, "padding": int(padding),
           "max_resolution": MAX_RESOLUTION}
    payload = pickle.dumps(list(sys.path)) + pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
    triangles = sum(len(m.triangles) for m in meshes)
    timeout = XATLAS_TIMEOUT_BASE + XATLAS_TIMEOUT_PER_TRIANGLE * triangles
    failures = []
    for _ in range(XATLAS_ATTEMPTS):
        try:
            run = subprocess.run([sys.executable, "-I", _WORKER], input=payload, capture_output=True,
                                 timeout=timeout)
        except subprocess.TimeoutExpired:
            failures.append(f"no answer after {timeout:.0f} s")
            continue
        if run.returncode == 0 and run.stdout:
            result = pickle.loads(run.stdout)
            if "error" in result:
                raise BakeError(result["error"])
            return result
        failures.append(_describe_failure(run))
    names = ", ".join(f"'{m.name}'" for m in meshes[:5]) + (" …" if len(meshes) > 5 else "")
    raise BakeError(f"xatlas failed {XATLAS_ATTEMPTS} times unwrapping {names}: {'; '.join(failures)}")


def _describe_failure(run) -> str:
    """One line on how the xatlas child ended: the signal that killed it or its last error line."""
    if run.returncode < 0:
        try:
            return f"crashed ({signal.Signals(-run.returncode).name})"
        except ValueError:
            return f"crashed (signal {-run.returncode})"
    lines = run.stderr.decode(errors="replace").strip().splitlines()
    return f"exit code {run.returncode}" + (f": {lines[-1]}" if lines else "")


def _object_uv(mesh, atlas, k, atlas_index, w, h):
    # xatlas normalises UVs by its own width/height; rescale to the final atlas size.
    scale = np.array([atlas["width"] / w, atlas["height"] / h], dtype=np.float64)
    uv = (atlas["uv"][k] * scale).astype(np.float32)                    # (T, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    areas = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * w * h     # texels²
    live = areas > 0
    if live.any():
        px = uv[live].reshape(-1, 2) * [w, h]
        rect = (int(np.floor(px[:, 0].min())), int(np.floor(px[:, 1].min())),
                int(np.ceil(px[:, 0].max())), int(np.ceil(px[:, 1].max())))
    else:
        rect = (0, 0, 0, 0)
    return ObjectUV(mesh.name, uv, atlas_index, float(areas.sum()), rect, atlas["mesh_charts"][k])
