"""The bpy ↔ core bridge: reads Blender into core's plain data and writes results back.

`scene_data` turns the evaluated depsgraph into a `core.scene.BakeScene` (occluders, lights,
world); `mesh_data` reads meshes with foreach_get (the receivers' `SurfaceTriangles`, the
meshes to unwrap) and writes the lightmap UV layer; `settings` builds the bake's settings value
(`core.bake.PipelineSettings`) from `scene.hhd`, or from the CLI's read-only view of it overridden
by its options; `bake_session` is the bpy half of a bake (read the scene and settings, run
`core.bake`, load the written images); `denoiser` finds the
Open Image Denoise library Blender ships; `light_sets` and `probe_mode` hold the scene data the
settings (properties.py) and the previews (shaders/) both read: the light sets' weights and the
probe preview's mode. Nothing here is an operator or registers anything.

Besides `operators/`, `panels/`, `shaders/` and `cli/`, this is the only package that imports
bpy; `core/` never does.
"""
