"""bpy scene -> BakeScene (the only bpy reading for a bake's lighting and occluders).

Reads the evaluated depsgraph: every mesh instance visible to render (modifiers, instancing
and collection instances included) becomes occluding, reflecting geometry; lights and the
world are converted to the Cycles units `core.scene` documents; materials are evaluated by
`bridge.materials`. What is not supported yet is reported by name, never silently approximated;
negative lights (Cycles subtracts them: the tracer cannot) and non-finite or absurd values
(`materials.checked`) are refused by name.
"""

from __future__ import annotations

import numpy as np

from .. import blender_compat
from ..core import progress as core_progress
from ..core.errors import BakeError
from ..core.probes import ProbeGrid
from ..core.scene import AreaLight, BakeScene, PointLight, SpotLight, SunLight
from .materials import TextureCache, checked, triangle_emission
from .mesh_data import read_triangles, triangle_albedo


def _instance_triangles(instance, cache, notes, visit=None):
    """(triangles (T, 3, 3) world space, albedo (T, 3), texture index (T,), texture uv (T, 3, 2),
    emission (T, 3), its Light Group's name) of one mesh instance; `visit(instance, mesh)`, if
    given, sees its evaluated mesh first."""
    obj = instance.object
    mesh = obj.to_mesh()
    try:
        if visit is not None:
            visit(instance, mesh)
        tris = read_triangles(mesh, instance.matrix_world)
        if tris is None:
            return None
        positions, loops, mat_index = tris
        albedo, tex_index, tex_uv = triangle_albedo(obj, mesh, loops, mat_index, cache, notes)
        emission = triangle_emission(obj, mesh, loops, mat_index, cache, notes)
        return positions, albedo, tex_index, tex_uv, emission, _light_group(obj)
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
    m = checked(instance.matrix_world, f"light '{instance.object.name}': its transform")
    _check_light(instance.object.name, light)
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


def _check_light(name: str, light) -> None:
    """Refuse a light the bake cannot honour: non-finite or absurd values (`materials.checked`)
    and a negative power or colour (Cycles subtracts such a light; the tracer picks lights by
    their power and cannot)."""
    quantity, unit = ("strength", "W/m²") if light.type == 'SUN' else ("power", "W")
    checked(light.energy, f"light '{name}': its {quantity}")
    checked(light.color[:3], f"light '{name}': its colour")
    checked(np.array(light.color[:3]) * light.energy, f"light '{name}': its colour × {quantity}")
    for size in ("shadow_soft_size", "angle", "size", "size_y", "spot_size", "spot_blend"):
        if hasattr(light, size):
            checked(getattr(light, size), f"light '{name}': its {size.replace('_', ' ')}")
    if light.energy < 0.0:
        what = f"a negative {quantity} ({light.energy:g} {unit})"
    elif min(light.color[:3]) < 0.0:
        what = f"a negative colour {tuple(round(float(c), 3) for c in light.color[:3])}"
    else:
        return
    raise BakeError(
        f"light '{name}' has {what}: the bake cannot subtract light; give it a positive {quantity} "
        "or hide it from render"
    )


def _world(scene):
    world = scene.world
    if world is None:
        return None
    value = _world_value(scene)
    if value is not None and not hasattr(value, "radiance"):
        checked(value, f"world '{world.name}': its colour × strength")
        if (value < 0.0).any():
            raise BakeError(
                f"world '{world.name}' has a negative colour × strength {tuple(round(float(v), 3) for v in value)}: "
                "the bake cannot subtract light; give the Background a positive strength"
            )
    return value


def _world_value(scene):
    world = scene.world
    if world is None:
        return None
    if blender_compat.node_tree_of(world) is None:
        return checked(world.color[:3], f"world '{world.name}': its colour")
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
    strength = float(checked(node.inputs["Strength"].default_value, f"world '{world.name}': the Background Strength"))
    if strength < 0.0:
        raise BakeError(
            f"world '{world.name}' has a negative Background Strength ({strength:g}): the bake cannot "
            "subtract light; give it a positive strength"
        )
    if node.inputs["Color"].is_linked:
        return _environment(world, node.inputs["Color"].links[0].from_node, strength)
    colour = checked(node.inputs["Color"].default_value[:3], f"world '{world.name}': the Background Color")
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
    radiance = checked(rgb * strength, f"world '{world.name}': the Environment Texture '{image.name}' × strength")
    if (radiance < 0.0).any():
        raise BakeError(
            f"world '{world.name}': the Environment Texture '{image.name}' has negative pixels: the bake "
            "cannot subtract light"
        )
    return EnvironmentMap(radiance, _vector_mapping(world, node))


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


def read_bake_scene(depsgraph, tick=None, visit=None) -> BakeScene:
    """BakeScene of everything visible to render in the evaluated depsgraph. `tick` (a
    `core.progress.Tick`) is told the share of the scene's objects read. `visit(instance, mesh)`,
    if given, is called for every object instance in order, with the evaluated mesh of a
    render-visible mesh instance (else None): the fingerprints read with the scene
    (`fingerprints.Reader`), each mesh evaluated once."""
    parts, lights, cache, notes = [], [], TextureCache(), []
    tick, total = core_progress.ticker(tick), max(len(depsgraph.objects), 1)
    for k, instance in enumerate(depsgraph.object_instances):
        tick.at(min(k / total, 1.0))
        obj = instance.object
        if obj.type == 'MESH' and not obj.hide_render:
            part = _instance_triangles(instance, cache, notes, visit)
            if part is not None:
                parts.append(part)
            continue
        if visit is not None:
            visit(instance, None)
        if obj.type == 'LIGHT':
            lights.append(_light(instance))
    if not parts:
        raise BakeError("nothing to bake: the scene has no mesh visible to render")
    tris, albedo, tex_index, tex_uv, emission = (np.concatenate(x) for x in list(zip(*parts))[:5])
    groups = [part[5] for part in parts]
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
        emission_group=np.repeat(groups, [len(part[0]) for part in parts]) if any(groups) else None,
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
        matrix = np.array(instance.matrix_world, dtype=np.float64)
        axes = np.linalg.norm(matrix[:3, :3], axis=0)
        if not np.isfinite(matrix).all() or abs(np.linalg.det(matrix[:3, :3])) <= 1e-9 * axes.prod():
            raise BakeError(
                f"irradiance volume '{obj.name}' has a zero scale on some axis, so its probes have no "
                "extent: give it a non-zero scale, or hide it from render to bake without it"
            )
        grids.append(ProbeGrid(obj.name, matrix, resolution, threshold))
    return grids
