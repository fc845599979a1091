"""What is wrong with an atlas's lightmap UVs before a bake: the Problems view's data. No bpy.

Per atlas (every object whose lightmap UVs share it), from the objects' `texel_density.ViewMesh`es:
- shared texels: texels that two charts or more overlap with positive area, found with the
  bake's own conservative rasteriser (`core.raster`), so exactly the texels whose bake points
  two surfaces would compete for. A chart is a set of one object's triangles joined through
  corners at the same UV point (charts are padded apart, so different charts never share a UV
  point; vertex indices are not used: meshes with split vertices would split charts). Triangles
  of one chart share texels along their common edges, which is no problem;
- flipped faces: UV winding opposite to their chart's (the sign of the chart's summed signed UV
  area), i.e. a chart folded over itself;
- degenerate faces: faces with area in the world but (next to) none in UV space, below
  DEGENERATE_RATIO of the atlas's target density: they get no texel of their own;
- objects with fewer than `min_texels` texels (`core.unwrap.FEW_TEXELS` by default, the unwrap's
  warning), too few to show any lighting detail.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import raster, unwrap
from . import charting, texel_density

#: The Problems view's colours (linear RGB): texels shared by two charts, flipped faces,
#: degenerate faces, every face of an object with too few texels; faces without a problem are grey.
SHARED_COLOUR = (1.0, 0.0, 1.0)
FLIPPED_COLOUR = (1.0, 0.3, 0.0)
DEGENERATE_COLOUR = (1.0, 0.9, 0.0)
FEW_COLOUR = (0.1, 0.4, 1.0)
#: A face whose texel density is below this share of the target has no UV area to speak of.
DEGENERATE_RATIO = 1e-3
#: World areas below this share of the object's largest triangle are zero (collapsed faces the
#: artist cannot see either: the unwrap gives them UV 0 too).
ZERO_WORLD_AREA = 1e-12


def charts(uv: np.ndarray) -> np.ndarray:
    """Chart label (T,) per triangle of one object's UVs (T, 3, 2): triangles joined through
    corners at the same UV point share a label (the smallest UV point id of the chart)."""
    uv = np.asarray(uv)
    if not len(uv):
        return np.zeros(0, np.int64)
    points, key = np.unique(uv.reshape(-1, 2), axis=0, return_inverse=True)
    return charting.connected_parts(key.reshape(-1, 3).astype(np.int64), len(points))


@dataclass
class ObjectProblems:
    """One object's problems: texels (UV area in texels), shared (how many of the atlas's shared
    texels its faces cover), flipped / degenerate (T,) per triangle, few (below min_texels)."""

    name: str
    texels: float
    shared: int
    flipped: np.ndarray
    degenerate: np.ndarray
    few: bool
    #: polygons with a flipped / degenerate triangle (what the report counts as faces)
    flipped_faces: int = 0
    degenerate_faces: int = 0

    @property
    def count(self) -> int:
        """Problems found: shared texels + flipped + degenerate faces (+1 when too few texels)."""
        return self.shared + self.flipped_faces + self.degenerate_faces + int(self.few)

    def line(self) -> str:
        """The report's line: "'Floor': 0 shared texels, 0 flipped, 0 degenerate faces (1234 texels)"
        (faces: polygons)."""
        few = ", too few texels" if self.few else ""
        return (
            f"'{self.name}': {self.shared} shared texels, {self.flipped_faces} flipped, "
            f"{self.degenerate_faces} degenerate faces ({self.texels:.0f} texels{few})"
        )


@dataclass
class AtlasProblems:
    """width × height atlas; shared: sorted flat ids (j · width + i) of the texels two charts or
    more overlap; objects: per ViewMesh, in order."""

    width: int
    height: int
    shared: np.ndarray
    objects: list[ObjectProblems] = field(default_factory=list)

    def mask(self) -> np.ndarray:
        """(height, width) bool image of the shared texels, row j = texel row j (v upwards)."""
        out = np.zeros(self.width * self.height, dtype=bool)
        out[self.shared] = True
        return out.reshape(self.height, self.width)


def find(
    meshes: list[texel_density.ViewMesh],
    width: int,
    height: int,
    target: float | None = None,
    min_texels: float = unwrap.FEW_TEXELS,
    threads: int = 0,
) -> AtlasProblems:
    """The problems of one width × height atlas holding `meshes` (module docstring). target:
    texels per metre the degenerate test compares with (default: `texel_density.target_density`
    of the meshes); threads: the rasteriser's (0 = every core)."""
    densities = [texel_density.density(m, width, height) for m in meshes]
    target = target or texel_density.target_density(densities)
    labels, offset = [], 0
    for m in meshes:
        local = charts(m.uv)
        labels.append(local + offset)
        offset += int(local.max()) + 1 if len(local) else 0
    starts = np.cumsum([0] + [len(m.uv) for m in meshes])
    uv = np.concatenate([m.uv for m in meshes]) if meshes else np.zeros((0, 3, 2))
    chart = np.concatenate(labels) if labels else np.zeros(0, np.int64)
    cov = raster.rasterise(uv, width, height, threads=threads) if len(uv) else None
    if cov is None or not len(cov.texel):
        shared = np.zeros(0, np.int64)
        owner = texel = np.zeros(0, np.int64)
    else:
        pairs = np.unique(cov.texel * max(offset, 1) + chart[cov.triangle])  # (texel, chart), once each
        texels, counts = np.unique(pairs // max(offset, 1), return_counts=True)
        shared = texels[counts > 1]
        hit = np.isin(cov.texel, shared)
        owner = np.searchsorted(starts, cov.triangle[hit], side="right") - 1
        texel = cov.texel[hit]
    objects = []
    for k, (m, d) in enumerate(zip(meshes, densities)):
        signed = texel_density.uv_areas(m.uv, width, height)
        world = texel_density.world_areas(m.corners)
        local = labels[k]
        winding = np.sign(np.bincount(local - local.min(), signed)[local - local.min()]) if len(local) else signed
        flipped = (signed * winding < 0) & (world > 0)
        seen = world > ZERO_WORLD_AREA * (world.max() if len(world) else 0.0)
        degenerate = seen & (np.abs(signed) <= (DEGENERATE_RATIO * target) ** 2 * world)
        flipped &= ~degenerate
        mine = np.unique(texel[owner == k])
        objects.append(
            ObjectProblems(
                m.name,
                d.total_texels,
                len(mine),
                flipped,
                degenerate,
                d.total_texels < min_texels,
                len(np.unique(m.polygon[flipped])),
                len(np.unique(m.polygon[degenerate])),
            )
        )
    return AtlasProblems(width, height, shared, objects)


def polygon_flags(mesh: texel_density.ViewMesh, problems: ObjectProblems) -> tuple[np.ndarray, np.ndarray]:
    """(flipped, degenerate) (polygons,) bool: a polygon with any such triangle."""
    flipped = np.bincount(mesh.polygon, problems.flipped, minlength=mesh.polygons) > 0
    degenerate = np.bincount(mesh.polygon, problems.degenerate, minlength=mesh.polygons) > 0
    return flipped, degenerate


def face_colours(mesh: texel_density.ViewMesh, problems: ObjectProblems) -> np.ndarray:
    """(polygons, 3) linear RGB factors of the Problems view: 1 (no problem), else the colour of
    the polygon's worst problem (degenerate, then flipped, then too few texels)."""
    flipped, degenerate = polygon_flags(mesh, problems)
    out = np.ones((mesh.polygons, 3))
    if problems.few:
        out[:] = FEW_COLOUR
    out[flipped] = FLIPPED_COLOUR
    out[degenerate] = DEGENERATE_COLOUR
    return out


def legend_text() -> str:
    """The Problems view's legend in words."""
    return (
        "magenta: texels shared by two charts · orange: flipped faces · yellow: degenerate faces · blue: too few texels"
    )
