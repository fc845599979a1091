"""The embedded demo scene, built with bpy: a room with a window, a sun, a sky, a coloured wall
and a normal-mapped panel. Used by tools/demo.py (and later by end-to-end tests)."""
from __future__ import annotations

import math

import bpy
import numpy as np
from hhd_lightmapper import blender_compat

ROOM = (6.0, 4.0, 3.0)           # x, y, z extent in metres, floor at z = 0
WINDOW = (-1.0, 1.0, 1.0, 2.2)   # in the +x wall: y range, z range
SUN_DIRECTION_DEG = (35.0, 20.0)  # elevation, azimuth (from +x towards +y): shines in through the window
SKY_COLOUR = (0.35, 0.55, 1.0)


def _material(name, colour, normal_image=None):
    mat = bpy.data.materials.new(name)
    blender_compat.ensure_node_tree(mat)
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    if normal_image is not None:
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = normal_image
        tex.image.colorspace_settings.name = "Non-Color"
        nmap = nodes.new("ShaderNodeNormalMap")
        links.new(tex.outputs["Color"], nmap.inputs["Color"])
        links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def _box(name, lo, hi, material):
    """An axis-aligned box mesh from corner lo to corner hi (outward normals)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    verts = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
             (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _bumps_normal_map(size=128):
    """A tangent-space normal map of round bumps, generated here (no files needed)."""
    u = (np.arange(size) + 0.5) / size
    x, y = np.meshgrid(u, u)
    h = np.cos(2 * np.pi * 4 * x) * np.cos(2 * np.pi * 4 * y)
    gy, gx = np.gradient(h * 0.08, 1.0 / size)
    n = np.stack([-gx, -gy, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    rgba = np.concatenate([n * 0.5 + 0.5, np.ones((size, size, 1))], axis=-1)
    img = bpy.data.images.new("panel_normal", size, size, float_buffer=False)
    img.pixels.foreach_set(rgba.astype(np.float32).ravel())
    img.pack()
    return img


def build() -> dict:
    """Replace the current scene's content with the demo room; return its key objects."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    sx, sy, sz = ROOM
    t = 0.2
    white = _material("Plaster", (0.8, 0.8, 0.78))
    red = _material("Red Paint", (0.75, 0.12, 0.08))
    panel_mat = _material("Panel", (0.6, 0.6, 0.6), _bumps_normal_map())
    objs = {
        "floor": _box("Floor", (-sx / 2, -sy / 2, -t), (sx / 2, sy / 2, 0.0), white),
        "ceiling": _box("Ceiling", (-sx / 2, -sy / 2, sz), (sx / 2, sy / 2, sz + t), white),
        "wall_back": _box("Wall -X", (-sx / 2 - t, -sy / 2, 0.0), (-sx / 2, sy / 2, sz), white),
        "wall_red": _box("Wall +Y (red)", (-sx / 2, sy / 2, 0.0), (sx / 2, sy / 2 + t, sz), red),
        "wall_front": _box("Wall -Y", (-sx / 2, -sy / 2 - t, 0.0), (sx / 2, -sy / 2, sz), white),
    }
    # The +x wall, built around the window opening.
    y0, y1, z0, z1 = WINDOW
    x0, x1 = sx / 2, sx / 2 + t
    for i, (lo, hi) in enumerate([((x0, -sy / 2, 0.0), (x1, y0, sz)), ((x0, y1, 0.0), (x1, sy / 2, sz)),
                                  ((x0, y0, 0.0), (x1, y1, z0)), ((x0, y0, z1), (x1, y1, sz))]):
        objs[f"wall_window_{i}"] = _box(f"Wall +X {i}", lo, hi, white)
    objs["panel"] = _box("Normal-mapped Panel", (-sx / 2, -0.8, 0.6), (-sx / 2 + 0.05, 0.8, 2.0), panel_mat)

    elevation, azimuth = (math.radians(a) for a in SUN_DIRECTION_DEG)
    sun_data = bpy.data.lights.new("Sun", "SUN")
    sun_data.energy = 5.0                    # W/m², Cycles units
    sun_data.angle = math.radians(1.0)
    sun = bpy.data.objects.new("Sun", sun_data)
    # A sun light shines along its local -Z; point it from the sky through the window (+x side).
    towards = (math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation))
    sun.rotation_euler = _rotation_pointing(tuple(-c for c in towards))
    scene.collection.objects.link(sun)
    objs["sun"] = sun

    world = bpy.data.worlds.new("Sky")
    blender_compat.ensure_node_tree(world)
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*SKY_COLOUR, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 16.0
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = (2.6, -1.6, 1.6)
    cam.rotation_euler = _rotation_pointing((-1.0, 0.45, -0.08), camera=True)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return objs


def _rotation_pointing(direction, camera=False):
    """Euler rotation turning local -Z onto `direction` (Blender lights and cameras look down -Z)."""
    from mathutils import Vector
    return Vector(direction).to_track_quat("-Z", "Y").to_euler()


def sun_direction() -> np.ndarray:
    """Unit vector towards the sun (world space)."""
    e, a = (math.radians(v) for v in SUN_DIRECTION_DEG)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def externalise_images(folder) -> None:
    """Save generated/packed images as PNG files next to the .blend and use those: EEVEE in
    background mode (the bpy module) renders in-memory images black."""
    from pathlib import Path
    for image in bpy.data.images:
        if image.source == 'GENERATED' or image.packed_file is not None:
            path = Path(folder) / f"{image.name}.png"
            image.filepath_raw = str(path)
            image.file_format = 'PNG'
            image.save()
            if image.packed_file is not None:
                image.unpack(method='REMOVE')
            image.source = 'FILE'
            image.filepath = str(path)
            image.reload()
