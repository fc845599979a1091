"""Scene builders with bpy: clear the file, add materials, boxes, planes, lights, worlds,
cameras, select and unwrap. Used by the bpy tests (tests/cycles_compare.py compares bakes of
scenes built with it) and by the named scenes of scenekit/scenes.py (benches, tools/demo.py).

bpy is imported inside each function, so importing this module does not start Blender: a test
or bench may import it before it isolates Blender's user configuration.

Two kinds of box, both kept as they are because the tests' and benches' figures depend on them:
`box` is Blender's cube primitive scaled by its object transform (the test scenes), `box_between`
a mesh whose vertices are the world-space corners, identity transform (the demo and bench scenes).
"""

from __future__ import annotations

import numpy as np

from hhd_lightmapper import blender_compat

#: the test scenes' lightmap UV layer and atlas size (set by `clear_scene`)
LAYER = "HHD_Lightmap"
RES = 256


def clear_data(worlds: bool = False) -> None:
    """Remove every object, mesh, light, material and image (and world, with `worlds`)."""
    import bpy

    collections = [bpy.data.objects, bpy.data.meshes, bpy.data.lights, bpy.data.materials, bpy.data.images]
    if worlds:
        collections.append(bpy.data.worlds)
    for collection in collections:
        for block in list(collection):
            collection.remove(block)


def clear_scene():
    """An empty scene for the tests: no world, Cycles on the CPU without adaptive sampling or
    denoising, every core (Render > Performance > Threads: Auto), the lightmap settings at their
    defaults but LAYER / RES in one shared atlas, and no light sets listed (a .blend an earlier
    test opened may have left other settings). Returns the scene."""
    import bpy

    clear_data()
    scene = bpy.context.scene
    scene.world = None
    scene.render.threads_mode = 'AUTO'
    for prop in scene.hhd.bl_rna.properties:  # every HHD setting at its default (an opened .blend set them)
        if prop.identifier != "rna_type" and not prop.is_readonly:
            scene.hhd.property_unset(prop.identifier)
    scene.hhd.light_sets.clear()
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.hhd.uv_layer = LAYER
    scene.hhd.resolution = RES
    scene.hhd.atlas_mode = 'SHARED'
    scene.hhd.texel_density = 0.0
    return scene


def material(name, colour=(0.8, 0.8, 0.8), emission=None, normal_image=None):
    """A rough (1.0) Principled BSDF of base `colour`; emission: (r, g, b, strength); normal_image:
    a tangent-space normal map (e.g. `bumps_normal_map()`) through a Normal Map node."""
    import bpy

    mat = bpy.data.materials.new(name)
    blender_compat.ensure_node_tree(mat)
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    if emission is not None:
        bsdf.inputs["Emission Color"].default_value = (*emission[:3], 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission[3]
    if normal_image is not None:
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = normal_image
        tex.image.colorspace_settings.name = "Non-Color"
        nmap = nodes.new("ShaderNodeNormalMap")
        links.new(tex.outputs["Color"], nmap.inputs["Color"])
        links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def textured_material(name, left_rgb, right_rgb, uv_map=None, size=8):
    """Principled BSDF whose Base Color is an sRGB byte image: left half one colour, right half
    another (values given in sRGB, as an artist paints them), optionally through a UV Map node."""
    import bpy

    mat = material(name)
    image = bpy.data.images.new(name + "_albedo", size, size, float_buffer=False)
    px = np.zeros((size, size, 4))
    px[:, : size // 2, :3] = left_rgb
    px[:, size // 2 :, :3] = right_rgb
    px[..., 3] = 1.0
    image.pixels.foreach_set(px.astype(np.float32).ravel())
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = 'Closest'
    links.new(tex.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    if uv_map:
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = uv_map
        links.new(uv.outputs["UV"], tex.inputs["Vector"])
    return mat


def bumps_normal_map(size=128):
    """A tangent-space normal map of round bumps, generated here (no files needed), packed."""
    import bpy

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


def box(name, centre, size, mat):
    """Blender's cube primitive at `centre`, scaled (object scale) to `size` (x, y, z)."""
    import bpy

    bpy.ops.mesh.primitive_cube_add(location=centre)
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = [s / 2 for s in size]
    obj.data.materials.append(mat)
    return obj


def box_between(name, lo, hi, material):
    """An axis-aligned box mesh from corner lo to corner hi (outward normals, quads), its
    vertices in world space (identity transform), linked to the scene collection."""
    import bpy

    from .meshes import BOX_QUADS, box_corners

    verts, faces = box_corners(lo, hi), BOX_QUADS
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def plane(name, centre, size, mat, rotation=(0, 0, 0)):
    """Blender's plane primitive (`size` wide) at `centre`, rotated (Euler XYZ, radians)."""
    import bpy

    bpy.ops.mesh.primitive_plane_add(size=size, location=centre, rotation=rotation)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def world(colour, strength=1.0, name="World"):
    """A constant-colour world (Background colour × strength), made the scene's world."""
    import bpy

    w = bpy.data.worlds.new(name)
    blender_compat.ensure_node_tree(w)
    w.node_tree.nodes["Background"].inputs["Color"].default_value = (*colour, 1.0)
    w.node_tree.nodes["Background"].inputs["Strength"].default_value = strength
    bpy.context.scene.world = w
    return w


EEVEE_WORLD = "EEVEE black world"


def eevee_fast_lighting(scene) -> None:
    """Shrink what EEVEE redoes for lighting at every render: the world's light probe at 128²
    (the default 1024² sphere probe is rendered again at every render; with no world, a black
    one named EEVEE_WORLD is made, which looks as none does) and a 16 MB shadow pool (512 MB
    cleared at every render). For the preview renders: an Emission shader reads neither, so its
    pixels stay bit for bit the same (a lit material's world light comes through the coarser
    probe). On llvmpipe a small render takes a fifth of the time. Idempotent."""
    import bpy

    if scene.world is None:
        world = bpy.data.worlds.get(EEVEE_WORLD)
        if world is None:
            world = bpy.data.worlds.new(EEVEE_WORLD)
            world.color = (0.0, 0.0, 0.0)
            for node in world.node_tree.nodes if world.node_tree else ():
                if node.type == 'BACKGROUND':
                    node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        scene.world = world
    if scene.world.probe_resolution != '128':
        scene.world.probe_resolution = '128'
    if scene.eevee.shadow_pool_size != '16':
        scene.eevee.shadow_pool_size = '16'


def sky_pixels(h=32, w=64, sun=(0.75, 0.3), sun_radiance=200.0):
    """An equirectangular float image (H, W, 4), row 0 at the bottom: a blue sky brightening
    towards the zenith, a dim ground, and a 3×3-pixel "sun" at image coordinates `sun` (u, v)."""
    v = (np.arange(h) + 0.5) / h
    z = np.cos(np.pi * (1.0 - v))
    px = np.zeros((h, w, 4))
    px[..., :3] = np.where(
        z[:, None, None] > 0, (0.2 + 0.8 * z[:, None, None]) * np.array([0.3, 0.5, 1.0]), np.array([0.05, 0.04, 0.03])
    )
    r, c = int(sun[1] * h), int(sun[0] * w)
    px[r - 1 : r + 2, c - 1 : c + 2, :3] = sun_radiance * np.array([1.0, 0.9, 0.8])
    px[..., 3] = 1.0
    return px


def hdri_world(pixels, strength=1.0, rotation=None):
    """World = Environment Texture (a float image) × strength, optionally through a Mapping
    node rotating it (Euler XYZ, radians)."""
    import bpy

    h, w = pixels.shape[:2]
    image = bpy.data.images.new("sky", w, h, float_buffer=True, alpha=True)
    image.pixels.foreach_set(pixels.astype(np.float32).ravel())
    wld = bpy.data.worlds.new("HDRI")
    blender_compat.ensure_node_tree(wld)
    nodes, links = wld.node_tree.nodes, wld.node_tree.links
    env = nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    links.new(env.outputs["Color"], nodes["Background"].inputs["Color"])
    nodes["Background"].inputs["Strength"].default_value = strength
    if rotation is not None:
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Rotation"].default_value = rotation
        coords = nodes.new("ShaderNodeTexCoord")
        links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    bpy.context.scene.world = wld
    return wld


def light(kind, location=(0, 0, 0), rotation=(0, 0, 0), energy=1.0, name=None, **props):
    """A light of `kind` ('SUN', 'POINT', 'SPOT', 'AREA'; its data and object named `name`,
    else `kind`), other light properties as keywords (angle=, size=, spot_size=, ...)."""
    import bpy

    data = bpy.data.lights.new(name or kind, kind)
    data.energy = energy
    for k, v in props.items():
        setattr(data, k, v)
    obj = bpy.data.objects.new(name or kind, data)
    obj.location, obj.rotation_euler = location, rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


def rotation_pointing(direction):
    """Euler rotation turning local -Z onto `direction` (Blender lights and cameras look down -Z)."""
    from mathutils import Vector

    return Vector(direction).to_track_quat("-Z", "Y").to_euler()


def sun(elevation_deg, azimuth_deg, strength, angle_deg):
    """A sun light "Sun" shining from elevation / azimuth (degrees, azimuth from +x towards +y):
    `strength` in W/m² (Cycles units), angular diameter `angle_deg`."""
    import math

    import bpy

    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    data = bpy.data.lights.new("Sun", "SUN")
    data.energy, data.angle = strength, math.radians(angle_deg)
    obj = bpy.data.objects.new("Sun", data)
    towards = (math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e))
    obj.rotation_euler = rotation_pointing(tuple(-c for c in towards))
    bpy.context.scene.collection.objects.link(obj)
    return obj


def camera(location, direction, lens=18.0):
    """The scene camera "Camera" at `location` looking along `direction`."""
    import bpy

    data = bpy.data.cameras.new("Camera")
    data.lens = lens
    cam = bpy.data.objects.new("Camera", data)
    cam.location = location
    cam.rotation_euler = rotation_pointing(direction)
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    return cam


def select(objs):
    """Select exactly `objs` (objects just linked included) and make the first active."""
    import bpy

    bpy.context.view_layer.update()
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]


def unwrap(receivers, texel_density: float = 0.0):
    """Select `receivers` and run the add-on's Unwrap on them (the scene's HHD settings; a
    `texel_density` in texels per metre replaces the fixed Resolution)."""
    import bpy

    bpy.context.scene.hhd.texel_density = texel_density
    select(receivers)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}


def externalise_images(folder) -> None:
    """Save generated/packed images as PNG files in `folder` and use those: EEVEE in background
    mode (the bpy module) renders in-memory images black."""
    from pathlib import Path

    import bpy

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


def scene_hash(objects: bool = False) -> str:
    """Hash of what a bake, a view or an export must not change: every mesh's UV layers, every
    material's node tree (nodes, inputs, links) and every image's identity and source; with
    `objects`, every object's location and recorded atlas too."""
    import hashlib

    import bpy

    h = hashlib.sha256()
    for mesh in sorted(bpy.data.meshes, key=lambda m: m.name):
        for layer in mesh.uv_layers:
            uv = np.zeros(len(mesh.loops) * 2, np.float32)
            layer.data.foreach_get("uv", uv)
            h.update(layer.name.encode() + uv.tobytes())
    for mat in sorted(bpy.data.materials, key=lambda m: m.name):
        h.update(mat.name.encode())
        for node in mat.node_tree.nodes:
            h.update(f"{node.name}{node.bl_idname}{tuple(node.location)}".encode())
            for socket in node.inputs:
                value = getattr(socket, "default_value", None)
                h.update(repr(tuple(value) if hasattr(value, "__len__") else value).encode())
        for link in mat.node_tree.links:
            h.update(
                f"{link.from_node.name}.{link.from_socket.identifier}>{link.to_node.name}.{link.to_socket.identifier}".encode()
            )
    for image in sorted(bpy.data.images, key=lambda i: i.name):
        h.update(f"{image.name}|{image.filepath}|{image.packed_file is not None}".encode())
    if objects:
        for obj in sorted(bpy.data.objects, key=lambda o: o.name):
            h.update(f"{obj.name}{tuple(obj.matrix_world.col[3])}{obj.hhd.atlas}".encode())
        h.update(f"{len(bpy.data.materials)} {len(bpy.data.images)} {len(bpy.data.meshes)}".encode())
    return h.hexdigest()


def two_lamp_room(floor_grey=(0.8, 0.8, 0.8), box_white=(0.8, 0.8, 0.8)):
    """A 4 m floor and a box lit by a lamp in the Light Group "Red" and one in "Blue" under a dim
    world, unwrapped into one 256² atlas and selected (the small light-set bake of the CLI and
    export tests). Returns (scene, [floor, box])."""
    scene = clear_scene()
    floor = plane("Floor", (0, 0, 0), 4, material("grey", floor_grey))
    cube = box("Box", (0.5, 0.3, 0.4), (0.8, 0.8, 0.8), material("white", box_white))
    red = light('POINT', (-1.0, -1.0, 1.5), energy=150.0, name="RedLamp")
    blue = light('POINT', (1.2, 1.0, 1.2), energy=100.0, name="BlueLamp")
    world((0.05, 0.05, 0.08))
    red.lightgroup, blue.lightgroup = "Red", "Blue"
    scene.hhd.resolution, scene.hhd.texel_density = 256, 0.0
    unwrap([floor, cube])
    select([floor, cube])
    return scene, [floor, cube]
