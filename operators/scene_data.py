"""bpy scene -> BakeScene (the only bpy reading for a bake's lighting and occluders).

Reads the evaluated depsgraph: every mesh instance visible to render (modifiers, instancing
and collection instances included) becomes occluding, reflecting geometry; lights and the
world are converted to the Cycles units `core.scene` documents. What is not supported yet is
reported by name, never silently approximated.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import BakeError
from ..core.scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight
from .mesh_data import TextureCache, read_triangles, triangle_albedo


def _material_emission(mat) -> tuple:
    """Emitted radiance (linear RGB) of a material: a Principled BSDF's Emission Color ×
    Strength, or an Emission shader feeding the output; black otherwise."""
    if mat is None or not mat.use_nodes or mat.node_tree is None:
        return (0.0, 0.0, 0.0)
    nodes = mat.node_tree.nodes
    output = next((n for n in nodes if n.type == 'OUTPUT_MATERIAL' and n.is_active_output), None)
    surface = output.inputs["Surface"].links[0].from_node if output and output.inputs["Surface"].is_linked else None
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
    emission (T, 3)) of one mesh instance."""
    obj = instance.object
    mesh = obj.to_mesh()
    try:
        tris = read_triangles(mesh, instance.matrix_world)
        if tris is None:
            return None
        positions, loops, mat_index = tris
        albedo, tex_index, tex_uv = triangle_albedo(obj, mesh, loops, mat_index, cache, notes)
        emission = np.array([_material_emission(s.material) for s in obj.material_slots] or [(0.0, 0.0, 0.0)])
        return positions, albedo, tex_index, tex_uv, emission[np.minimum(mat_index, len(emission) - 1)]
    finally:
        obj.to_mesh_clear()


def _light(instance):
    light = instance.object.data
    m = np.array(instance.matrix_world, dtype=np.float64)
    colour = np.array(light.color[:3], dtype=np.float64)
    if light.type == 'SUN':
        towards = m[:3, 2] / np.linalg.norm(m[:3, 2])        # lights shine along their local -Z
        return SunLight(towards, colour * light.energy, float(light.angle))
    if light.type == 'POINT':
        return PointLight(m[:3, 3].copy(), colour * light.energy, float(light.shadow_soft_size),
                          bool(getattr(light, "use_soft_falloff", True)))
    if light.type == 'SPOT':
        axis = -m[:3, 2] / np.linalg.norm(m[:3, 2])
        return SpotLight(m[:3, 3].copy(), colour * light.energy, float(light.shadow_soft_size),
                         bool(getattr(light, "use_soft_falloff", True)), axis,
                         float(light.spot_size), float(light.spot_blend))
    if light.type == 'AREA':
        size_x = light.size
        size_y = light.size if light.shape in ('SQUARE', 'DISK') else light.size_y
        if getattr(light, "spread", np.pi) < np.pi - 1e-6:
            raise BakeError(f"light '{instance.object.name}': area lights with a spread below 180° are not "
                            "supported by the bake yet")
        return AreaLight(m[:3, 3].copy(), m[:3, 0] * 0.5 * size_x, m[:3, 1] * 0.5 * size_y,
                         -m[:3, 2] / np.linalg.norm(m[:3, 2]), colour * light.energy, light.shape)
    raise BakeError(f"light '{instance.object.name}': {light.type.lower()} lights are not supported by the "
                    "bake yet; hide it from render to bake without it")


def _world(scene):
    world = scene.world
    if world is None:
        return None
    if not world.use_nodes or world.node_tree is None:
        return np.array(world.color[:3], dtype=np.float64)
    output = next((n for n in world.node_tree.nodes if n.type == 'OUTPUT_WORLD' and n.is_active_output), None)
    if output is None or not output.inputs["Surface"].is_linked:
        return None
    node = output.inputs["Surface"].links[0].from_node
    if node.type != 'BACKGROUND':
        raise BakeError(f"world '{world.name}': only a Background shader is supported by the bake yet")
    if node.inputs["Color"].is_linked:
        raise BakeError(f"world '{world.name}': a textured background (HDRI, sky) is not supported by the "
                        "bake yet; use a plain Background colour")
    colour = np.array(node.inputs["Color"].default_value[:3], dtype=np.float64)
    return colour * float(node.inputs["Strength"].default_value)


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
    tris, albedo, tex_index, tex_uv, emission = (np.concatenate(x) for x in zip(*parts))
    return BakeScene(tris, albedo, emission, lights, _world(depsgraph.scene),
                     texture_index=tex_index, texture_uv=tex_uv, textures=cache.images, notes=notes)
