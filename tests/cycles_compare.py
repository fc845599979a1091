"""Bake the same receivers with our tracer and with Cycles' Diffuse bake (Direct + Indirect,
Color off: irradiance in DESIGN.md's unit) and compare I_z texel by texel, with a tolerance
derived from both estimators' measured noise."""
import numpy as np
from hhd_lightmapper import blender_compat

LAYER = "HHD_Lightmap"
RES = 256


def cycles_footprint() -> float:
    """Width (texels) of the square Cycles' Diffuse bake averages a texel over in the running
    Blender: the whole texel from 5.2.1, the central ½ × ½ before (halved UV differentials)."""
    import bpy
    return 1.0 if bpy.app.version >= (5, 2, 1) else 0.5


def clear_scene():
    import bpy
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.lights, bpy.data.materials, bpy.data.images):
        for block in list(collection):
            collection.remove(block)
    scene = bpy.context.scene
    scene.world = None
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.hhd.uv_layer = LAYER
    scene.hhd.resolution = RES
    scene.hhd.atlas_mode = 'SHARED'
    scene.hhd.texel_density = 0.0
    return scene


def material(name, colour=(0.8, 0.8, 0.8), emission=None):
    import bpy
    mat = bpy.data.materials.new(name)
    blender_compat.ensure_node_tree(mat)
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    if emission is not None:
        bsdf.inputs["Emission Color"].default_value = (*emission[:3], 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission[3]
    return mat


def box(name, centre, size, mat):
    import bpy
    bpy.ops.mesh.primitive_cube_add(location=centre)
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = [s / 2 for s in size]
    obj.data.materials.append(mat)
    return obj


def plane(name, centre, size, mat, rotation=(0, 0, 0)):
    import bpy
    bpy.ops.mesh.primitive_plane_add(size=size, location=centre, rotation=rotation)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def world(colour):
    import bpy
    w = bpy.data.worlds.new("World")
    blender_compat.ensure_node_tree(w)
    w.node_tree.nodes["Background"].inputs["Color"].default_value = (*colour, 1.0)
    w.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
    bpy.context.scene.world = w


def sky_pixels(h=32, w=64, sun=(0.75, 0.3), sun_radiance=200.0):
    """An equirectangular float image (H, W, 4), row 0 at the bottom: a blue sky brightening
    towards the zenith, a dim ground, and a 3×3-pixel "sun" at image coordinates `sun` (u, v)."""
    v = (np.arange(h) + 0.5) / h
    z = np.cos(np.pi * (1.0 - v))
    px = np.zeros((h, w, 4))
    px[..., :3] = np.where(z[:, None, None] > 0, (0.2 + 0.8 * z[:, None, None]) * np.array([0.3, 0.5, 1.0]),
                           np.array([0.05, 0.04, 0.03]))
    r, c = int(sun[1] * h), int(sun[0] * w)
    px[r - 1:r + 2, c - 1:c + 2, :3] = sun_radiance * np.array([1.0, 0.9, 0.8])
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


def light(kind, location=(0, 0, 0), rotation=(0, 0, 0), energy=1.0, **props):
    import bpy
    data = bpy.data.lights.new(kind, kind)
    data.energy = energy
    for k, v in props.items():
        setattr(data, k, v)
    obj = bpy.data.objects.new(kind, data)
    obj.location, obj.rotation_euler = location, rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


def select(objs):
    """Select exactly `objs` (objects just linked included) and make the first active."""
    import bpy
    bpy.context.view_layer.update()
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]


def unwrap(receivers):
    import bpy
    select(receivers)
    assert bpy.ops.hhd.unwrap() == {'FINISHED'}


def ours(receivers, samples, bounces, seed):
    import bpy
    from hhd_lightmapper.core import bakepoints, hhd, rays, tracer
    from hhd_lightmapper.operators import mesh_data, scene_data
    depsgraph = bpy.context.evaluated_depsgraph_get()
    surface = mesh_data.read_surface(receivers, LAYER, depsgraph)
    scene = scene_data.read_bake_scene(depsgraph)
    points = bakepoints.build(surface, RES, RES, occluders=rays.RayScene(scene.triangles))
    result = tracer.bake(points, scene, tracer.BakeSettings(samples=samples, pass_samples=16,
                                                            bounces=bounces, seed=seed))
    return points, hhd.irradz(result.sh, points.normal), result


def cycles(receivers, points, samples, bounces, seed):
    import bpy
    scene = bpy.context.scene
    scene.cycles.samples = samples
    scene.cycles.seed = seed
    scene.cycles.max_bounces = bounces
    scene.cycles.diffuse_bounces = bounces
    scene.cycles.glossy_bounces = scene.cycles.transmission_bounces = 0
    scene.cycles.sample_clamp_direct = scene.cycles.sample_clamp_indirect = 0.0
    image = bpy.data.images.get("cycles_bake") or bpy.data.images.new("cycles_bake", RES, RES, float_buffer=True)
    for obj in receivers:
        for mat in obj.data.materials:
            node = mat.node_tree.nodes.get("hhd_bake_target") or mat.node_tree.nodes.new("ShaderNodeTexImage")
            node.name = "hhd_bake_target"
            node.image = image
            mat.node_tree.nodes.active = node
    select(receivers)
    bpy.ops.object.bake(type='DIFFUSE', pass_filter={'DIRECT', 'INDIRECT'}, margin=0, use_clear=True,
                        uv_layer=LAYER)
    px = np.array(image.pixels[:], dtype=np.float64).reshape(RES * RES, 4)[:, :3]
    return px[points.texel]


def compare(receivers, samples=64, bounces=1, cycles_samples=64):
    """(mean I_z, bias, residual RMS, expected RMS from noise) over fully covered texels."""
    points, o1, _ = ours(receivers, samples, bounces, seed=1)
    _, o2, _ = ours(receivers, samples, bounces, seed=2)
    c1 = cycles(receivers, points, cycles_samples, bounces, seed=1)
    c2 = cycles(receivers, points, cycles_samples, bounces, seed=2)
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    o, c = 0.5 * (o1 + o2)[keep], 0.5 * (c1 + c2)[keep]
    # Each mean of two runs has variance (σ²)/2 per texel, and σ² ≈ E[(run1 - run2)²]/2.
    texel_noise = ((o1 - o2)[keep] ** 2 + (c1 - c2)[keep] ** 2) / 4    # per texel, each channel
    noise = np.mean(texel_noise)
    return dict(points=points, keep=keep, ours=o, cycles=c, mean=float(np.mean(c)), texel_noise=texel_noise,
                bias=float(np.mean(o - c)), rms=float(np.sqrt(np.mean((o - c) ** 2))),
                noise_rms=float(np.sqrt(noise)), se_mean=float(np.sqrt(noise / o.size)))


def assert_agree(r, allowance=0.01):
    """Unbiased within 4 standard errors of the mean (plus `allowance` × mean I_z for what is
    not noise: e.g. Cycles' shading-normal smoothing), and per-texel residual consistent with
    the two estimators' noise (≤ 1.5× the expected RMS, plus the same allowance)."""
    tol_bias = 4 * r["se_mean"] + allowance * r["mean"]
    assert abs(r["bias"]) <= tol_bias, (r["bias"], tol_bias, r["mean"])
    assert r["rms"] <= 1.5 * r["noise_rms"] + allowance * r["mean"], (r["rms"], r["noise_rms"], r["mean"])


def textured_material(name, left_rgb, right_rgb, uv_map=None, size=8):
    """Principled BSDF whose Base Color is an sRGB byte image: left half one colour, right half
    another (values given in sRGB, as an artist paints them), optionally through a UV Map node."""
    import bpy
    mat = material(name)
    image = bpy.data.images.new(name + "_albedo", size, size, float_buffer=False)
    px = np.zeros((size, size, 4))
    px[:, : size // 2, :3] = left_rgb
    px[:, size // 2:, :3] = right_rgb
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
