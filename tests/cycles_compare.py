"""Bake the same receivers with our tracer and with Cycles' Diffuse bake (Direct + Indirect,
Color off: irradiance in the unit of docs/conventions.md#irradiance-units) and compare I_z texel by
texel, with a tolerance derived from both estimators' measured noise. The scenes are built with
scenekit/blender.py."""

import numpy as np

from scenekit.blender import LAYER, select


def cycles_footprint() -> float:
    """Width (texels) of the square Cycles' Diffuse bake averages a texel over in the running
    Blender: the whole texel from 5.2.1, the central ½ × ½ before (halved UV differentials)."""
    import bpy

    return 1.0 if bpy.app.version >= (5, 2, 1) else 0.5


def atlas_size(receivers) -> tuple[int, int]:
    """(width, height) of the atlas the receivers were unwrapped into (one for all)."""
    sizes = {(o.hhd.atlas_width, o.hhd.atlas_height) for o in receivers}
    assert len(sizes) == 1, sizes
    return sizes.pop()


def ours(receivers, samples, bounces, seed):
    """(bake points, I_z (P, 3), the traced atlas) of our bake of `receivers` with `seed`."""
    return ours_seeds(receivers, samples, bounces, (seed,))[0]


def ours_seeds(receivers, samples, bounces, seeds):
    """`ours` for each of `seeds`: the scene is read and the bake points are built once, and
    traced once per seed (the traces are what differ between seeds)."""
    import bpy

    from hhd_lightmapper.bridge import mesh_data, scene_data
    from hhd_lightmapper.core import bake, hhd, tracer

    depsgraph = bpy.context.evaluated_depsgraph_get()
    surface = mesh_data.read_surface(receivers, LAYER, depsgraph)
    scene = scene_data.read_bake_scene(depsgraph)
    ray_scene = bake.ray_scene_of(scene)
    width, height = atlas_size(receivers)
    atlas = bake.AtlasInput(
        "atlas", width, height, surface, [str(k) for k in range(int(surface.object_index.max()) + 1)]
    )
    points = bake.points_of(atlas, ray_scene)
    runs = []
    for seed in seeds:
        settings = tracer.BakeSettings(samples=samples, pass_samples=16, bounces=bounces, seed=seed)
        traced = tracer.bake(points, scene, settings, ray_scene=ray_scene)
        runs.append((traced.points, hhd.irradz(traced.sh, traced.points.normal), traced))
    return runs


def cycles(receivers, points, samples, bounces, seed):
    import bpy

    scene = bpy.context.scene
    scene.cycles.samples = samples
    scene.cycles.seed = seed
    scene.cycles.max_bounces = bounces
    scene.cycles.diffuse_bounces = bounces
    scene.cycles.glossy_bounces = scene.cycles.transmission_bounces = 0
    scene.cycles.sample_clamp_direct = scene.cycles.sample_clamp_indirect = 0.0
    width, height = atlas_size(receivers)
    image = bpy.data.images.get("cycles_bake")
    if image is None or tuple(image.size) != (width, height):
        image = bpy.data.images.new("cycles_bake", width, height, float_buffer=True)
    for obj in receivers:
        for mat in obj.data.materials:
            node = mat.node_tree.nodes.get("hhd_bake_target") or mat.node_tree.nodes.new("ShaderNodeTexImage")
            node.name = "hhd_bake_target"
            node.image = image
            mat.node_tree.nodes.active = node
    select(receivers)
    bpy.ops.object.bake(type='DIFFUSE', pass_filter={'DIRECT', 'INDIRECT'}, margin=0, use_clear=True, uv_layer=LAYER)
    px = np.array(image.pixels[:], dtype=np.float64).reshape(width * height, 4)[:, :3]
    return px[points.texel]


def compare(receivers, samples=64, bounces=1, cycles_samples=64):
    """(mean I_z, bias, residual RMS, expected RMS from noise) over fully covered texels."""
    (points, o1, _), (_, o2, _) = ours_seeds(receivers, samples, bounces, (1, 2))
    c1 = cycles(receivers, points, cycles_samples, bounces, seed=1)
    c2 = cycles(receivers, points, cycles_samples, bounces, seed=2)
    keep = (points.coverage >= 1.0 - 1e-9) & ~points.buried
    o, c = 0.5 * (o1 + o2)[keep], 0.5 * (c1 + c2)[keep]
    # Each mean of two runs has variance (σ²)/2 per texel, and σ² ≈ E[(run1 - run2)²]/2.
    texel_noise = ((o1 - o2)[keep] ** 2 + (c1 - c2)[keep] ** 2) / 4  # per texel, each channel
    noise = np.mean(texel_noise)
    return dict(
        points=points,
        keep=keep,
        ours=o,
        cycles=c,
        mean=float(np.mean(c)),
        texel_noise=texel_noise,
        bias=float(np.mean(o - c)),
        rms=float(np.sqrt(np.mean((o - c) ** 2))),
        noise_rms=float(np.sqrt(noise)),
        se_mean=float(np.sqrt(noise / o.size)),
    )


def restricted(r, subset):
    """`compare`'s result over a `subset` (bool over its compared texels) of them."""
    o, c, noise = r["ours"][subset], r["cycles"][subset], r["texel_noise"][subset]
    keep = r["keep"].copy()
    keep[keep] = subset
    return dict(
        r,
        keep=keep,
        ours=o,
        cycles=c,
        texel_noise=noise,
        mean=float(np.mean(c)),
        bias=float(np.mean(o - c)),
        rms=float(np.sqrt(np.mean((o - c) ** 2))),
        noise_rms=float(np.sqrt(np.mean(noise))),
        se_mean=float(np.sqrt(np.mean(noise) / o.size)),
    )


def assert_agree(r, allowance=0.01):
    """Unbiased within 4 standard errors of the mean (plus `allowance` × mean I_z for what is
    not noise: e.g. Cycles' shading-normal smoothing), and per-texel residual consistent with
    the two estimators' noise (≤ 1.5× the expected RMS, plus the same allowance)."""
    tol_bias = 4 * r["se_mean"] + allowance * r["mean"]
    assert abs(r["bias"]) <= tol_bias, (r["bias"], tol_bias, r["mean"])
    assert r["rms"] <= 1.5 * r["noise_rms"] + allowance * r["mean"], (r["rms"], r["noise_rms"], r["mean"])
