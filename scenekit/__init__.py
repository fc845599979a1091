"""The scene kit: the one place test, bench and tool scenes are built (not shipped in the
extension: blender_manifest.toml excludes it).

Which module for what:

- `scenekit.meshes`  numpy meshes, no bpy: plane, cube, uv_sphere, slivers, bumpy_quads, ngon,
                     combine, vertex_normals, `sphere_field` (the benches' displaced spheres),
                     and UV-layout checks (uv_charts, texel_overlaps). For core tests and benches
                     that feed core directly.
- `scenekit.blender` bpy builders: clear_scene / clear_data, material, textured_material,
                     bumps_normal_map, box (cube primitive), box_between (corner to corner),
                     plane, world, sky_pixels + hdri_world, light, sun, camera, select, unwrap,
                     externalise_images. For bpy tests and custom scenes.
- `scenekit.leak_fixtures`  numpy, no bpy: the leak audit's fixtures (a wall through a floor, a
                     box on a floor, a thin wall between a lit and a dark room, a thin table top)
                     with each texel's exact answer; tests/test_leaks.py bakes them with the
                     core, bench/leaks.py also in Blender against Cycles.
- `scenekit.synthetic`  numpy, no bpy: analytic lighting environments as hemisphere-sampled
                     radiance SH (`hemisphere_sh`, `benchmark_set`, `random_normals`) for the
                     encoder's tests and bench/encoder.py.
- `scenekit.light_set_reference`  numpy, no bpy: `parameter_blend`, the blend of light sets'
                     HHD parameters the talk warns against (tests and bench/light_sets.py
                     compare `core.light_sets.blend` with it).
- `scenekit.bakepoint_reference`  no bpy: the bake points before the leak fixes settled them
                     (`unsettled`, `trace_unsettled`), what tests/test_leaks.py,
                     tests/test_unwrap_raster.py and bench/leaks.py measure the fixes against.
- `scenekit.estimator_reference`  no bpy: the texel estimator with some of its numbers drawn
                     pass by pass, not from each texel's own sequences across its passes
                     (`used(*parts)`), what tests/test_tracer.py, tests/test_emitter_clusters.py,
                     bench/estimator.py and bench/light_sampling.py measure it against.
- `scenekit.scenes`  named whole scenes: demo_room (the README's demo), outdoor / emissive (with
                     the demo room bench/tradeoff.py's three, `build(name)`), classroom and
                     field (bench/time_to_error.py's, against Cycles).

Import it as the top-level package `scenekit`: the development install (`pip install -e .`,
pyproject.toml) installs it beside `hhd_lightmapper` (it is not part of the extension). It imports
`hhd_lightmapper` for `blender_compat` and core; bpy only inside the builders, so importing the
kit does not start Blender.

The scenes' names, geometry and materials are what the tests' tolerances and the benches'
recorded figures were measured on: change them only together with those.
"""
