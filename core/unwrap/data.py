"""The unwrap's inputs and outputs: the meshes and settings it takes, the UVs and atlases it
returns, the charts it caches, and the checks of a mesh before charting. No bpy."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import BakeError

MIN_RESOLUTION, MAX_RESOLUTION = 256, 8192


class AtlasFull(BakeError):
    """The charts of these objects do not fit one atlas at the chosen resolution (or, with a
    texel density, within MAX_RESOLUTION²): `unwrap` then spreads the objects over several."""


@dataclass
class UnwrapMesh:
    """name: object name (for messages); positions (V, 3) world space, metres; triangles (T, 3)
    vertex indices; resolution / texel_density: per-object overrides (None = the settings');
    polygons: (T,) index ≥ 0 of the polygon each triangle belongs to (its triangles stay in one
    chart, its corners on one vertex share one UV); None: every triangle is its own polygon.
    instance_of: the name of the mesh (datablock) the object uses; objects naming the same mesh
    share one lightmap UV layer and become instances (`core.unwrap.instances`); None: never shared.
    bundle: (collection, instancer, member) for a mesh a collection instance shows: the object
    `member` of `collection` as the Empty `instancer` places it (positions in world space through
    the instancer); it is an instance of `instance_of` even when no other object shares it, and
    the collection's members are placed together per instancer (`core.unwrap.instances.Bundle`)."""

    name: str
    positions: np.ndarray
    triangles: np.ndarray
    resolution: int | None = None
    texel_density: float | None = None
    polygons: np.ndarray | None = None
    instance_of: str | None = None
    bundle: tuple[str, str, str] | None = None


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
    charts cover (UV area × width × height); rect: (x0, y0, x1, y1) texel bounds in the atlas.
    An instance (`core.unwrap.instances`) also has layer_uv (T, 3, 2), the UVs its mesh's lightmap
    layer holds (shared by every instance of the mesh), and instance = (scale u, scale v,
    offset u, offset v): uv = layer_uv · scale + offset. For other objects layer_uv is uv. A mesh
    of a collection instance also has inner (its rectangle in the collection's bundle) and outer
    (the instancer's copy of the bundle in the atlas): instance = outer ∘ inner."""

    name: str
    uv: np.ndarray
    atlas: int
    texels: float
    rect: tuple
    charts: int
    layer_uv: np.ndarray | None = None
    instance: tuple[float, float, float, float] | None = None
    inner: tuple[float, float, float, float] | None = None
    outer: tuple[float, float, float, float] | None = None

    @property
    def layer(self) -> np.ndarray:
        """What the object's lightmap UV layer holds (T, 3, 2)."""
        return self.uv if self.layer_uv is None else self.layer_uv


@dataclass
class UnwrapResult:
    """stats: how the unwrap went ("charted" / "cached" meshes, "chart_s" / "pack_s" seconds,
    "chart_processes", "packs": packs summed over atlases, "tries": per atlas, the densities
    packed and whether they fitted [(texels per metre, fitted)])."""

    objects: list[ObjectUV]
    atlas_sizes: list[tuple[int, int]]  # (width, height) per atlas
    utilisation: list[float]  # fraction of each atlas covered by charts (padding included)
    charts: int
    warnings: list[str] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    #: per atlas: whether it holds objects of the shared atlas (not an object's own), and its
    #: number among the atlases one group spilled into (0: the first or only one)
    shared: list[bool] = field(default_factory=list)
    part: list[int] = field(default_factory=list)
    #: per atlas: whether it holds instances (`core.unwrap.instances`)
    instanced: list[bool] = field(default_factory=list)


@dataclass(frozen=True)
class Charts:
    """One mesh cut into charts, in metres (see `xatlas_worker`): chart (T,) int32 chart id per
    triangle (-1: no area); corner (T, 3) int32 index into uv of each corner (-1 likewise), one
    per (chart, vertex); uv (U, 2) float32 chart-local coordinates; folded: polygons that overlap
    themselves however they are flattened (e.g. self-intersecting n-gons). Read-only (shared by
    the cache)."""

    chart: np.ndarray
    corner: np.ndarray
    uv: np.ndarray
    folded: int = 0

    @property
    def nbytes(self) -> int:
        return self.chart.nbytes + self.corner.nbytes + self.uv.nbytes


def padding_for_mips(mip_levels: int, base: int = 2) -> int:
    """Padding (texels) keeping charts apart down to the given mip level: base · 2^levels."""
    return base * (1 << max(0, mip_levels))


def validate(mesh: UnwrapMesh) -> None:
    """Raise BakeError naming the object if its geometry cannot be unwrapped."""
    p = np.asarray(mesh.positions)
    t = np.asarray(mesh.triangles)
    if t.size == 0:
        raise BakeError(f"'{mesh.name}' has no faces to unwrap")
    if p.ndim != 2 or p.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
        raise BakeError(f"'{mesh.name}': positions must be (V, 3) and triangles (T, 3), got {p.shape} and {t.shape}")
    if not np.isfinite(p).all():
        raise BakeError(f"'{mesh.name}' has NaN or infinite vertex coordinates")
    if t.min() < 0 or t.max() >= len(p):
        raise BakeError(f"'{mesh.name}' has faces that reference missing vertices")
    if mesh.polygons is not None:
        poly = np.asarray(mesh.polygons)
        if poly.shape != (len(t),) or not np.issubdtype(poly.dtype, np.integer) or poly.min() < 0:
            raise BakeError(
                f"'{mesh.name}': polygons must give one polygon index ≥ 0 per triangle "
                f"({len(t)}), got an array of shape {poly.shape} and type {poly.dtype}"
            )
    if not (triangle_areas(p, t) > 0).any():
        raise BakeError(f"'{mesh.name}' has only zero-area faces: nothing to bake")


def triangle_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area `(T,)` of each triangle (same units as positions, squared)."""
    p = np.asarray(positions, dtype=np.float64)[np.asarray(triangles)]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def _check_scale(resolution, density):
    if density is None and not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        raise BakeError(f"lightmap resolution {resolution} is outside {MIN_RESOLUTION}–{MAX_RESOLUTION}")
    if density is not None and not density > 0:
        raise BakeError(f"texel density must be positive, got {density}")
