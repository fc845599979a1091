"""The views before a bake (shaders/texel_views.py): objects' lightmap UVs in, per-face colours out.

Reads what the unwrap wrote, as the unwrap reads it (`mesh_data.read_unwrap_mesh`: the object's
own mesh before modifiers, world space, mirrored objects' winding reversed) plus the lightmap UV
layer per triangle corner (an instance's through its rectangle: atlas UVs), into a
`core.unwrap.texel_density.ViewMesh`. Writes a view's colours as a
FLOAT_VECTOR attribute on the face domain (`COLOUR`: not a colour attribute, so the mesh's active
and render colour attributes stay as they are), which Hide removes again.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import BakeError
from ..core.unwrap.texel_density import ViewMesh
from . import mesh_data

#: The face attribute (FLOAT_VECTOR, FACE domain) holding a view's linear RGB per polygon.
COLOUR = "hhd_view"


def read_view_mesh(obj, uv_layer: str) -> ViewMesh | None:
    """`obj`'s faces and atlas UVs (an instance's layer UVs through its rectangle,
    `mesh_data.lightmap_rect`, so each instance has its own texels), or None when its mesh has no
    layer `uv_layer` or no face."""
    mesh = obj.data
    layer = mesh.uv_layers.get(uv_layer)
    if layer is None:
        return None
    try:
        unwrap_mesh, loops = mesh_data.read_unwrap_mesh(obj)
    except BakeError:  # no faces
        return None
    uv = np.zeros(len(mesh.loops) * 2, dtype=np.float32)
    layer.data.foreach_get("uv", uv)
    rect = np.array(mesh_data.lightmap_rect(obj))  # an instance's rectangle (core.unwrap.instances)
    corners = uv.reshape(-1, 2)[loops] * rect[:2] + rect[2:]
    return ViewMesh.of(
        obj.name, unwrap_mesh.positions, unwrap_mesh.triangles, corners, unwrap_mesh.polygons, len(mesh.polygons)
    )


def write_face_colours(obj, rgb: np.ndarray) -> None:
    """Set the COLOUR face attribute of obj.data to `rgb` (polygons, 3), creating it if missing."""
    mesh = obj.data
    attribute = mesh.attributes.get(COLOUR)
    if attribute is not None and (attribute.data_type != 'FLOAT_VECTOR' or attribute.domain != 'FACE'):
        mesh.attributes.remove(attribute)
        attribute = None
    if attribute is None:
        attribute = mesh.attributes.new(COLOUR, 'FLOAT_VECTOR', 'FACE')
    attribute.data.foreach_set("vector", np.asarray(rgb, dtype=np.float32).ravel())
    mesh.update()


def remove_face_colours(obj) -> bool:
    """Remove the COLOUR attribute from obj's mesh; False if it had none."""
    mesh = getattr(obj, "data", None)
    attributes = getattr(mesh, "attributes", None)
    if attributes is None or attributes.get(COLOUR) is None:
        return False
    attributes.remove(attributes[COLOUR])
    mesh.update()
    return True
