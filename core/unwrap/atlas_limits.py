"""What an unwrap can hold, checked before xatlas runs. No bpy.

With a texel density an object's charts need about (surface area × density²) texels, and an
object is never split between atlases, so it must fit the largest atlas, `unwrap.MAX_RESOLUTION`²
texels. Far beyond that xatlas is asked for charts of billions of texels and dies in its child
process (SIGSEGV after a long wait); `check_density` refuses such an unwrap at once, naming the
object and the density that would fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import BakeError

#: Share of the largest atlas an object's charts may take at most (the rest: padding between
#: charts, packing gaps); the suggested density leaves that margin.
FILL = 0.5


def surface_area(positions: np.ndarray, triangles: np.ndarray) -> float:
    """Total area of the triangles (positions (V, 3), metres; triangles (T, 3) indices), m²."""
    p = np.asarray(positions, dtype=np.float64)[np.asarray(triangles)]
    return float(0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())


def fitting_density(area: float, max_resolution: int) -> float:
    """The largest texel density, rounded down to 2 significant digits, at which `area` m² of
    charts fill at most FILL of a max_resolution² atlas."""
    exact = max_resolution * math.sqrt(FILL / max(area, 1e-30))
    digits = 10 ** (math.floor(math.log10(exact)) - 1)
    return math.floor(exact / digits) * digits


def check_density(meshes: Sequence, density: float | None, max_resolution: int) -> None:
    """BakeError naming the first of `meshes` (`unwrap.UnwrapMesh`: name, positions,
    triangles, resolution / texel_density overrides) whose charts cannot fit one
    max_resolution² atlas at its texel density (its own override, else `density`; objects
    sized by a fixed resolution are not checked)."""
    for mesh in meshes:
        own = mesh.texel_density if mesh.texel_density is not None else None if mesh.resolution else density
        if not own:
            continue
        area = surface_area(mesh.positions, mesh.triangles)
        texels = area * own * own
        if texels > max_resolution * max_resolution:
            source = "its own Texel Density" if mesh.texel_density is not None else "the texel density"
            raise BakeError(
                f"'{mesh.name}': {source} of {own:g} per metre needs about {texels:.3g} texels for its "
                f"{area:.3g} m², more than the largest atlas holds ({max_resolution}² = "
                f"{max_resolution * max_resolution:.3g}): use at most {fitting_density(area, max_resolution):g} "
                "per metre"
            )
