"""bpy scene -> BakeScene (the only bpy reading for a bake's lighting and occluders).

Reads the evaluated depsgraph: every mesh instance visible to render (modifiers, instancing
and collection instances included) becomes occluding, reflecting geometry; lights and the
world are converted to the Cycles units `core.scene` documents. What is not supported yet is
reported by name, never silently approximated.
"""

from __future__ import annotations

import numpy as np

from .. import blender_compat
from ..core.errors import BakeError
from ..core.probes import ProbeGrid
from ..core.scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight
from .mesh_data import TextureCache, read_triangles, surface_node, triangle_albedo


def _material_emission(mat) -> tuple:
    """Emitted radiance (linear RGB) of a material: a Principled BSDF's Emission Color ×
    Strength, or an Emission shader feeding the output; black otherwise."""
    surface = surface_node(mat)
    if surface is None:
        return (0.0, 0.0, 0.0)
    if surface.type == 'EMISSION':
        colour, strength = surface.inputs["Color"].default_value[:3], surface.inputs["Strength"].default_value
    elif surface.type == 'BSDF_PRINCIPLED':
        colour = surface.inputs["Emission Color"].default_value[:3]
        strength = surface.inputs["Emission Strength"].default_value
    else:
        return (0.0, 0.0, 0.0)
    return tuple(float(c) * float(strength) for c in colour)


def _instance_triangles(instance, cache, notes):
    """(triangles (T, 3, 3) world space, albedo (T, 3), texture index (T,), texture uv (T, 3, 2),
    emission (T, 3), light group (T,)) of one mesh instance."""
    obj = instance.object
    mesh = obj.to_mesh()
    try:
        tris = read_triangles(mesh, instance.matrix_world)
        if tris is None:
            return None
        positions, loops, mat_index = tris
        albedo, tex_index, tex_uv = triangle_albedo(obj, mesh, loops, mat_index, cache, notes)
        emission = np.array([_material_emission(s.material) for s in obj.material_slots] or [(0.0, 0.0, 0.0)])
        group = np.full(len(positions), _light_group(obj), dtype=object)
        return positions, albedo, tex_index, tex_uv, emission[np.minimum(mat_index, len(emission) - 1)], group
    finally:
        obj.to_mesh_clear()


def _light_group(id_block) -> str:
    """The Light Group an object or world belongs to ("" = none), which is its light set
    (`core.light_sets`)."""
    return str(getattr(id_block, "lightgroup", "") or "")


def _light(instance):
    """The core light of a light object instance, in its Light Group's set."""
    data = _light_data(instance)
    data.group = _light_group(instance.object)
    return data


def _light_data(instance):
    light = instance.object.data
    m = np.array(instance.matrix_world, dtype=np.float64)
    colour = np.array(light.color[:3], dtype=np.float64)
    if light.type == 'SUN':
        towards = m[:3, 2] / np.linalg.norm(m[:3, 2])  # lights shine along their local -Z
        return SunLight(towards, colour * light.energy, float(light.angle))
    if light.type == 'POINT':
        return PointLight(
            m[:3, 3].copy(),
            colour * light.energy,
            float(light.shadow_soft_size),
            bool(getattr(light, "use_soft_falloff", True)),
        )
    if light.type == 'SPOT':
        axis = -m[:3, 2] / np.linalg.norm(m[:3, 2])
        return SpotLight(
            m[:3, 3].copy(),
            colour * light.energy,
            float(light.shadow_soft_size),
            bool(getattr(light, "use_soft_falloff", True)),
            axis,
            float(light.spot_size),
            float(light.spot_blend),
        )
    if light.type == 'AREA':
        size_x = light.size
        size_y = light.size if light.shape in ('SQUARE', 'DISK') else light.size_y
        if getattr(light, "spread", np.pi) < np.pi - 1e-6:
            raise BakeError(
                f"light '{instance.object.name}': area lights with a spread below 180° are not "
                "supported by the bake yet"
            )
        return AreaLight(
            m[:3, 3].copy(),
            m[:3, 0] * 0.5 * size_x,
            m[:3, 1] * 0.5 * size_y,
            -m[:3, 2] / np.linalg.norm(m[:3, 2]),
            colour * light.energy,
            light.shape,
        )
    raise BakeError(
        f"light '{instance.object.name}': {light.type.lower()} lights are not supported by the "
        "bake yet; hide it from render to bake without it"
    )


def _world(scene):
    world = scene.world
    if world is None:
        return None
    if blender_compat.node_tree_of(world) is None:
        return np.array(world.color[:3], dtype=np.float64)
    output = next((n for n in world.node_tree.nodes if n.type == 'OUTPUT_WORLD' and n.is_active_output), None)
    if output is None or not output.inputs["Surface"].is_linked:
        return None
    node = output.inputs["Surface"].links[0].from_node
    if node.type != 'BACKGROUND':
        raise BakeError(
            f"world '{world.name}': only a Background shader is supported by the bake "
            "(a plain colour or an Environment Texture)"
        )
    if node.inputs["Strength"].is_linked:
        raise BakeError(f"world '{world.name}': a linked Background Strength is not supported; set a value")
    strength = float(node.inputs["Strength"].default_value)
    if node.inputs["Color"].is_linked:
        return _environment(world, node.inputs["Color"].links[0].from_node, strength)
    colour = np.array(node.inputs["Color"].default_value[:3], dtype=np.float64)
    return colour * strength


def _environment(world, node, strength):
    """EnvironmentMap of an Environment Texture (equirectangular) feeding the Background, with the
    rotation/scale of a Mapping node on its Vector input."""
    from ..core.environment import EnvironmentMap
    from ..core.textures import srgb_to_linear

    if node.type != 'TEX_ENVIRONMENT':
        raise BakeError(
            f"world '{world.name}': the Background colour comes from a '{node.name}' node; the bake "
            "supports a plain colour or an Environment Texture feeding it directly"
        )
    if node.projection != 'EQUIRECTANGULAR':
        raise BakeError(
            f"world '{world.name}': Environment Texture projection {node.projection.title()} is not "
            "supported; use Equirectangular"
        )
    image = node.image
    if image is None or image.size[0] == 0 or image.size[1] == 0:
        raise BakeError(f"world '{world.name}': the Environment Texture has no image (or its file is missing)")
    w, h = image.size
    px = np.zeros(w * h * image.channels, dtype=np.float32)
    image.pixels.foreach_get(px)
    rgb = px.reshape(h, w, image.channels)[..., :3].astype(np.float64)
    if image.colorspace_settings.name == 'sRGB' and not image.is_float:
        rgb = srgb_to_linear(rgb)
    return EnvironmentMap(rgb * strength, _vector_mapping(world, node))


def _vector_mapping(world, node) -> np.ndarray:
    """3×3 world direction → lookup direction of the node's Vector input: identity when unlinked,
    a Mapping node's rotation/scale (its location does not move a direction and is ignored)."""
    if not node.inputs["Vector"].is_linked:
        return np.eye(3)
    mapping = node.inputs["Vector"].links[0].from_node
    source = mapping.inputs["Vector"].links[0].from_node if mapping.inputs["Vector"].is_linked else None
    if mapping.type != 'MAPPING' or (source is not None and source.type != 'TEX_COORD'):
        raise BakeError(
            f"world '{world.name}': the Environment Texture's Vector must come from a Mapping node "
            "(fed by Texture Coordinate or nothing)"
        )
    from mathutils import Euler

    for name in ("Rotation", "Scale"):
        if mapping.inputs[name].is_linked:
            raise BakeError(f"world '{world.name}': a linked Mapping {name} is not supported")
    rotation = np.array(Euler(mapping.inputs["Rotation"].default_value, 'XYZ').to_matrix(), dtype=np.float64)
    scale = np.diag(np.array(mapping.inputs["Scale"].default_value, dtype=np.float64))
    if not np.all(np.abs(np.diag(scale)) > 0):
        raise BakeError(f"world '{world.name}': the Mapping node has a zero scale")
    if mapping.vector_type in ('POINT', 'VECTOR'):
        return rotation @ scale
    if mapping.vector_type == 'TEXTURE':
        return np.linalg.inv(scale) @ rotation.T
    return rotation @ np.linalg.inv(scale)  # NORMAL: inverse-transpose of R·S


def read_bake_scene(depsgraph) -> BakeScene:
    """BakeScene of everything visible to render in the evaluated depsgraph."""
    parts, lights, cache, notes = [], [], TextureCache(), []
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type == 'LIGHT':
            lights.append(_light(instance))
        elif obj.type == 'MESH' and not obj.hide_render:
            part = _instance_triangles(instance, cache, notes)
            if part is not None:
                parts.append(part)
    if not parts:
        raise BakeError("nothing to bake: the scene has no mesh visible to render")
    tris, albedo, tex_index, tex_uv, emission, groups = (np.concatenate(x) for x in zip(*parts))
    world = _world(depsgraph.scene)
    world_group = _light_group(depsgraph.scene.world)
    constant, environment = (None, world) if hasattr(world, "radiance") else (world, None)
    if environment is not None:
        environment.group = world_group
    return BakeScene(
        tris,
        albedo,
        emission,
        lights,
        constant,
        texture_index=tex_index,
        texture_uv=tex_uv,
        textures=cache.images,
        notes=notes,
        environment=environment,
        emission_group=groups.astype(str) if groups.any() else None,
        world_group=world_group,
    )


def read_probe_grids(depsgraph) -> list[ProbeGrid]:
    """Every Irradiance Volume (light probe object of type VOLUME) visible to render, as a probe
    grid: its world matrix, resolution (`resolution_x/y/z`; `grid_resolution_*` on Blenders that
    name them so) and Validity Threshold."""
    grids = []
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type != 'LIGHT_PROBE' or obj.data.type not in ('VOLUME', 'GRID') or obj.hide_render:
            continue
        probe = obj.data
        resolution = tuple(
            int(getattr(probe, f"resolution_{a}", None) or getattr(probe, f"grid_resolution_{a}")) for a in "xyz"
        )
        threshold = float(getattr(probe, "validity_threshold", 0.4))
        grids.append(ProbeGrid(obj.name, np.array(instance.matrix_world, dtype=np.float64), resolution, threshold))
    return grids
