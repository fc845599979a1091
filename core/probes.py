"""Light probe volumes: grids of L2 radiance SH for what a lightmap cannot cover. No bpy.

A `ProbeGrid` is one of Blender's Irradiance Volume objects: its object matrix maps the local
cube [-1, 1]³ to the world, and its resolution (nx, ny, nz) places one probe at the centre of
every cell, as EEVEE does (`lightprobe_irradiance_grid_sample_position`):
    local = (i + ½) / n · 2 − 1 per axis,  world = to_world · local.
`bake` traces every probe with the lightmap's path tracer over the whole sphere
(`tracer.sphere.ProbeEstimator`: same lights, bounces and light sets) into world-space radiance
SH (docs/conventions.md#what-the-sh-store). A probe whose rays mostly hit the back of triangles
(inside a closed mesh, behind a wall's modelled side) is invalid: its share of front hits (rays that
escape count as front) is below the volume's Validity Threshold, EEVEE's own setting (0.4 by
default). It takes the mean of its valid neighbours (`fill_invalid`), as engines do. `sample` interpolates a grid trilinearly between
probe centres, clamped at the border, as EEVEE samples its volumes.

Files per volume (docs/format.md, "Probe volumes"): `<volume>_probes.exr`, 27 float channels
SH0.R … SH8.B and Validity.V, the grid's z slices stacked along the image's rows, and its
section of `probes.json` (transform, resolution, validity, light sets).
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import light_sets
from .errors import BakeError
from .files import exr
from .scene import BakeScene
from .tracer import scheduler
from .tracer.paths import TraceScene
from .tracer.settings import BakeSettings
from .tracer.sphere import ProbeEstimator, back_face_fraction
from .tracer.statistics import Statistics

#: EEVEE's default Validity Threshold: the share of front-face hits below which a probe is invalid.
VALIDITY_THRESHOLD = 0.4
#: Rays per probe of the validity test.
VALIDITY_RAYS = 64
PROBES_FORMAT = "hhd-probes"
PROBES_FORMAT_VERSION = 1
SIDECAR = "probes.json"
_NAME = re.compile(r"[^A-Za-z0-9_\-.]")


@dataclass
class ProbeGrid:
    """One probe volume: name (the object's), to_world (4, 4) object matrix of the local cube
    [-1, 1]³, resolution (nx, ny, nz) ≥ 1 probes per axis, validity_threshold: the share of a
    probe's rays that must first hit front faces (or escape) for it to be valid."""

    name: str
    to_world: np.ndarray
    resolution: tuple[int, int, int]
    validity_threshold: float = VALIDITY_THRESHOLD

    def __post_init__(self):
        self.to_world = np.asarray(self.to_world, dtype=np.float64).reshape(4, 4)
        self.resolution = tuple(int(r) for r in self.resolution)  # type: ignore[assignment]
        if min(self.resolution) < 1:
            raise BakeError(f"probe volume '{self.name}': its resolution {self.resolution} must be ≥ 1 per axis")
        if abs(np.linalg.det(self.to_world[:3, :3])) < 1e-12:
            raise BakeError(f"probe volume '{self.name}': its transform has a zero scale; give it a size")

    @property
    def count(self) -> int:
        return int(np.prod(self.resolution))

    def local_positions(self) -> np.ndarray:
        """`(N, 3)` cell centres in the local cube, x fastest, then y, then z."""
        axes = [(np.arange(n) + 0.5) / n * 2.0 - 1.0 for n in self.resolution]
        z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    def positions(self) -> np.ndarray:
        """`(N, 3)` world-space probe positions, x fastest, then y, then z."""
        local = self.local_positions()
        return local @ self.to_world[:3, :3].T + self.to_world[:3, 3]

    def grid_coordinates(self, points: np.ndarray) -> np.ndarray:
        """`(M, 3)` continuous probe indices (probe i at i) of world `points` `(M, 3)`."""
        local = (np.asarray(points, dtype=np.float64) - self.to_world[:3, 3]) @ np.linalg.inv(self.to_world[:3, :3]).T
        return (local + 1.0) * 0.5 * np.array(self.resolution) - 0.5


@dataclass
class BakedProbes:
    """A traced grid: sh `(N, 9, 3)` world-space radiance SH (invalid probes filled), valid (N,)
    bool, back_faces (N,) the validity test's back-face share, sets / set_sh `(K, N, 9, 3)`: the
    light sets' SH (none without light groups), samples per probe, seconds, rays."""

    grid: ProbeGrid
    sh: np.ndarray
    valid: np.ndarray
    back_faces: np.ndarray
    sets: tuple[str, ...] = ()
    set_sh: np.ndarray | None = None
    samples: int = 0
    seconds: float = 0.0
    rays: int = 0
    warnings: list[str] = field(default_factory=list)


def bake(
    grid: ProbeGrid,
    scene: BakeScene,
    settings: BakeSettings,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    trace_scene: TraceScene | None = None,
) -> BakedProbes:
    """Trace every probe of `grid` with `settings` (samples, pass_samples, bounces, seed,
    threads, light_sets; no noise target), test validity and fill the invalid probes."""
    start = time.perf_counter()
    settings = replace(settings.resolved(), noise_target=0.0, time_budget=0.0)
    ts = trace_scene or TraceScene(scene, settings.bounces, light_sets=settings.light_sets)
    positions = grid.positions()
    back = back_face_fraction(ts, positions, VALIDITY_RAYS, settings.seed)
    valid = 1.0 - back >= grid.validity_threshold
    warnings = []
    if not valid.any():
        warnings.append(
            f"probe volume '{grid.name}': every probe sees mostly back faces (normals facing away "
            "from the volume?): none was marked invalid; recalculate the normals outside"
        )
        valid[:] = True
    estimator = ProbeEstimator(positions, ts, settings.pass_samples)
    stats = Statistics(len(positions), np.tile([0.0, 0.0, 1.0], (len(positions), 1)), ts.channels)
    outcome = scheduler.run(estimator, stats, settings, start, progress, cancel)
    mean, _ = stats.result()
    shape = grid.resolution[::-1]
    mean = fill_invalid(mean.reshape(*shape, 9, -1), valid.reshape(shape)).reshape(len(positions), 9, -1)
    sets, set_sh = ts.sets, None
    sh = mean
    if sets:
        set_sh = np.ascontiguousarray(mean.reshape(len(positions), 9, len(sets), 3).transpose(2, 0, 1, 3))
        sh = set_sh.sum(axis=0)
    return BakedProbes(
        grid,
        sh,
        valid,
        back,
        sets,
        set_sh,
        samples=int(np.max(stats.passes, initial=0)) * settings.pass_samples,
        seconds=time.perf_counter() - start,
        rays=outcome.rays,
        warnings=warnings,
    )


def fill_invalid(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """`values` `(nz, ny, nx, ...)` with every invalid probe (valid (nz, ny, nx) False) set to the
    mean of its valid face neighbours, ring after ring outwards (probes filled in one ring count
    as valid for the next); probes no valid probe reaches take the mean of all valid ones."""
    out = np.array(values, dtype=np.float64, copy=True)
    known = np.array(valid, dtype=bool, copy=True)
    if known.all() or not known.any():
        return out
    extra = (1,) * (out.ndim - 3)
    while not known.all():
        total = np.zeros_like(out)
        count = np.zeros(known.shape)
        for axis in range(3):
            for step in (1, -1):
                shifted, mask = _shift(out, known, axis, step)
                total += shifted * mask.reshape(mask.shape + extra)
                count += mask
        grow = ~known & (count > 0)
        if not grow.any():
            break
        out[grow] = total[grow] / count[grow].reshape(-1, *extra)
        known |= grow
    if not known.all():
        out[~known] = out[known].mean(axis=0)
    return out


def _shift(values: np.ndarray, known: np.ndarray, axis: int, step: int):
    """(values, known) moved one probe along `axis` by `step`, with nothing known beyond the border."""
    shifted = np.roll(values, step, axis=axis)
    mask = np.roll(known, step, axis=axis).astype(float)
    edge = [slice(None)] * 3
    edge[axis] = slice(0, 1) if step > 0 else slice(-1, None)
    mask[tuple(edge)] = 0.0
    return shifted, mask


def sample(grid: ProbeGrid, sh: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Radiance SH `(M, 9, C)` at world `points` `(M, 3)`: trilinear between the probes of `sh`
    `(N, 9, C)` (grid order), clamped to the outermost probes (as EEVEE samples a volume)."""
    res = np.array(grid.resolution)
    g = np.clip(grid.grid_coordinates(points), 0.0, res - 1)
    lo = np.minimum(np.floor(g).astype(int), res - 1)
    hi = np.minimum(lo + 1, res - 1)
    f = g - lo
    grid_sh = sh.reshape(res[2], res[1], res[0], *sh.shape[1:])
    out = np.zeros((len(g), *sh.shape[1:]))
    for corner in range(8):
        pick = [(hi if corner >> a & 1 else lo)[:, a] for a in range(3)]
        w = np.prod([f[:, a] if corner >> a & 1 else 1.0 - f[:, a] for a in range(3)], axis=0)
        out += w[:, None, None] * grid_sh[pick[2], pick[1], pick[0]]
    return out


# ---- files ------------------------------------------------------------------------------------


def file_stem(volume: str, light_set: str | None = None) -> str:
    """`<volume>` or `<volume>.<set>`, reduced to letters, digits, '_', '-' and '.'."""
    stem = _NAME.sub("_", volume)
    return stem if light_set is None else light_sets.set_atlas_name(stem, light_set)


def probe_image(sh: np.ndarray, valid: np.ndarray, grid: ProbeGrid) -> dict[str, np.ndarray]:
    """EXR channels of one grid: SH0.R … SH8.B and Validity.V, float32 `(ny·nz, nx)`, in the
    EXR's own row order (top row first): row y + ny·z, column x holds probe (x, y, z)."""
    nx, ny, nz = grid.resolution
    flat = sh.reshape(nz * ny, nx, 9, 3).astype(np.float32)
    out = {f"SH{m}.{c}": flat[:, :, m, k] for m in range(9) for k, c in enumerate("RGB")}
    out["Validity.V"] = valid.reshape(nz * ny, nx).astype(np.float32)
    return out


def write(staging, folder: Path, baked: list[BakedProbes]) -> dict:
    """Stage every grid's EXR (and each light set's) and `probes.json` in `folder`; returns the
    sidecar document."""
    volumes = []
    for b in baked:
        stem = file_stem(b.grid.name)
        exr.write_file(staging.stage(folder / f"{stem}_probes.exr"), probe_image(b.sh, b.valid, b.grid))
        set_files = []
        for k, name in enumerate(b.sets):
            set_stem = file_stem(b.grid.name, name)
            assert b.set_sh is not None
            exr.write_file(staging.stage(folder / f"{set_stem}_probes.exr"), probe_image(b.set_sh[k], b.valid, b.grid))
            set_files.append({"name": name, "file": f"{set_stem}_probes.exr"})
        volumes.append(
            {
                "name": b.grid.name,
                "file": f"{stem}_probes.exr",
                "resolution": list(b.grid.resolution),
                "to_world": b.grid.to_world.tolist(),
                "probes": b.grid.count,
                "invalid": int((~b.valid).sum()),
                "validity_threshold": b.grid.validity_threshold,
                "samples": b.samples,
                "seconds": b.seconds,
                "rays": b.rays,
                "light_sets": set_files,
                "warnings": b.warnings,
            }
        )
    doc = {
        "format": PROBES_FORMAT,
        "format_version": PROBES_FORMAT_VERSION,
        "conventions": {
            "sh": "world-space L2 radiance SH over the whole sphere, basis of docs/conventions.md#sh-basis (Y00, Y1-1, Y10, Y11, ...)",
            "positions": "probe (x, y, z) at to_world · ((i + 0.5) / n · 2 − 1) per axis (EEVEE's cell centres)",
            "layout": "EXR row y + ny·z (top row first), column x",
        },
        "volumes": volumes,
    }
    staging.write_json(folder / SIDECAR, doc, indent=2)
    return doc


def read(folder: Path, volume: str, light_set: str | None = None) -> tuple[ProbeGrid, np.ndarray, np.ndarray]:
    """(grid, sh `(N, 9, 3)`, valid (N,)) of a baked volume (or one of its light sets) in `folder`."""
    path = Path(folder) / SIDECAR
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BakeError(f"no probes baked: {path} does not exist (bake with an Irradiance Volume)") from None
    entry = next((v for v in doc.get("volumes", []) if v["name"] == volume), None)
    if entry is None:
        raise BakeError(f"no probe volume '{volume}' in {path}")
    grid = ProbeGrid(
        entry["name"], np.array(entry["to_world"]), tuple(entry["resolution"]), entry["validity_threshold"]
    )
    file = (
        entry["file"] if light_set is None else next(s["file"] for s in entry["light_sets"] if s["name"] == light_set)
    )
    channels, _ = exr.read(Path(folder) / file)
    nx, ny, nz = grid.resolution
    sh = np.stack([np.stack([channels[f"SH{m}.{c}"] for c in "RGB"], axis=-1) for m in range(9)], axis=-2)
    return grid, sh.reshape(nx * ny * nz, 9, 3).astype(np.float64), channels["Validity.V"].reshape(-1) > 0.5
