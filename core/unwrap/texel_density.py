"""Texel density of lightmap UVs: texels per metre per face, against a target, as heat colours. No bpy.

The views before a bake (shaders/texel_views.py) read each object's lightmap UVs and world-space
triangles into a `ViewMesh`; this module gives, per polygon, its texel density: the linear
density sqrt(texels / m²) of the polygon's triangles together (texels = UV area × atlas width ×
height, as `core.unwrap.ObjectUV.texels` counts them), its ratio to the target, and the heat
colour of that ratio (`heat`, `LEGEND`).

The target (`target_density`): the texel density the unwrap packed at (the scene's or the
object's Texel Density setting), or, for a fixed resolution, the density the packer reached,
sqrt(Σ texels / Σ m²) over the atlas's objects (xatlas scales every chart to one density, so
that is what each face has where the charts are not stretched).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Heat colours of the density's ratio to the target (linear RGB), at log2(ratio) −1 … 1: half the
#: target blue, on target green, double red; beyond them the end colours.
LEGEND = (
    (0.5, "blue", (0.0, 0.1, 1.0)),
    (0.5**0.5, "cyan", (0.0, 0.8, 1.0)),
    (1.0, "green", (0.0, 0.9, 0.1)),
    (2.0**0.5, "yellow", (1.0, 0.85, 0.0)),
    (2.0, "red", (1.0, 0.05, 0.0)),
)


@dataclass
class ViewMesh:
    """One object's faces as the views read them: corners (T, 3, 3) world-space triangle
    corners (metres), uv (T, 3, 2) lightmap UVs of the atlas (in [0, 1]²), polygon (T,) the
    polygon each triangle belongs to, polygons: the object's polygon count."""

    name: str
    corners: np.ndarray
    uv: np.ndarray
    polygon: np.ndarray
    polygons: int

    @classmethod
    def of(cls, name, positions, triangles, uv, polygon=None, polygons=None) -> ViewMesh:
        """From vertex positions (V, 3), triangles (T, 3) of vertex indices and per-corner UVs
        (T, 3, 2); without polygons each triangle is its own."""
        triangles = np.asarray(triangles, dtype=np.int64)
        polygon = np.arange(len(triangles)) if polygon is None else np.asarray(polygon, dtype=np.int64)
        count = int(polygon.max()) + 1 if polygons is None and len(polygon) else (polygons or 0)
        return cls(
            name, np.asarray(positions, dtype=np.float64)[triangles], np.asarray(uv, dtype=np.float64), polygon, count
        )


def uv_areas(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Signed area of each UV triangle (T, 3, 2) in texels (counter-clockwise positive)."""
    p = np.asarray(uv, dtype=np.float64) * np.array([width, height], dtype=np.float64)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def world_areas(corners: np.ndarray) -> np.ndarray:
    """Area (m²) of each world-space triangle (T, 3, 3)."""
    c = np.asarray(corners, dtype=np.float64)
    return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)


def texels_per_metre(texels, area) -> np.ndarray:
    """Linear texel density sqrt(texels / area) (texels per metre); 0 where the area is 0."""
    texels, area = np.abs(np.asarray(texels, dtype=np.float64)), np.asarray(area, dtype=np.float64)
    return np.sqrt(np.divide(texels, area, out=np.zeros_like(area), where=area > 0))


@dataclass
class Density:
    """Per polygon of one object: texels (UV area in texels, unsigned), area (m²), density
    (texels per metre, `texels_per_metre`); and the object's totals."""

    texels: np.ndarray
    area: np.ndarray
    density: np.ndarray

    @property
    def total_texels(self) -> float:
        return float(self.texels.sum())

    @property
    def total_area(self) -> float:
        return float(self.area.sum())

    @property
    def mean_density(self) -> float:
        """The object's density: sqrt(Σ texels / Σ m²)."""
        return float(texels_per_metre(self.total_texels, self.total_area))


def density(mesh: ViewMesh, width: int, height: int) -> Density:
    """Texel density per polygon of `mesh` in a width × height atlas (its triangles summed)."""
    texels = np.bincount(mesh.polygon, np.abs(uv_areas(mesh.uv, width, height)), minlength=mesh.polygons)
    area = np.bincount(mesh.polygon, world_areas(mesh.corners), minlength=mesh.polygons)
    return Density(texels, area, texels_per_metre(texels, area))


def target_density(densities, setting: float | None = None) -> float:
    """The density to compare against: `setting` (texels per metre) when the atlas was unwrapped
    at one, else sqrt(Σ texels / Σ m²) over `densities` (the atlas's objects' `Density`s)."""
    if setting:
        return float(setting)
    return float(texels_per_metre(sum(d.total_texels for d in densities), sum(d.total_area for d in densities)))


def heat(ratio) -> np.ndarray:
    """Linear RGB (N, 3) of density ratios (N,): LEGEND's colours interpolated in log2(ratio),
    clamped to its ends; a ratio of 0 (no texels or no area) is the lowest colour."""
    ratio = np.asarray(ratio, dtype=np.float64)
    t = np.log2(np.maximum(ratio, 1e-30))
    stops = np.log2([r for r, _, _ in LEGEND])
    colours = np.array([c for _, _, c in LEGEND])
    return np.stack([np.interp(t, stops, colours[:, k]) for k in range(3)], axis=-1)


def legend_text() -> str:
    """The legend in words: 'blue ½× · cyan 0.71× · green 1× · yellow 1.41× · red 2× the target'."""
    return " · ".join(f"{name} {ratio:.3g}×" for ratio, name, _ in LEGEND) + " the target"
