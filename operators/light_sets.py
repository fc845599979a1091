"""Operators: light sets (`bpy.ops.hhd.refresh_light_sets()`, `bpy.ops.hhd.blend_light_sets()`).

A bake of a scene whose emitters use Light Groups writes one atlas per light set besides each
atlas's own files, listed in the atlas's sidecar under "light_sets" (core.light_sets). Refresh
lists those sets in `scene.hhd.light_sets` (keeping the weights already there); Blend writes the
blend of the sets at their current weights into each atlas's own files
(`core.light_sets.blend_atlas`) and reloads the images that show them.
"""

import bpy

from ..bridge import light_sets
from ..core.errors import BakeError


def refresh(scene) -> list[str]:
    """List the light sets of the last bake's atlases in `scene.hhd.light_sets`; returns every
    set name found (sorted)."""
    names = sorted(light_sets.atlas_sets(light_sets.scene_atlases(scene)))
    light_sets.sync_light_sets(scene, names)
    return names


class HHD_OT_refresh_light_sets(bpy.types.Operator):
    """List the light sets of the last bake (from its sidecars); weights already set are kept"""

    bl_idname = "hhd.refresh_light_sets"
    bl_label = "Refresh Light Sets"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        try:
            names = refresh(context.scene)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        self.report({'INFO'}, f"Light sets: {', '.join(names)}" if names else "The last bake has no light sets")
        return {'FINISHED'}


class HHD_OT_blend_light_sets(bpy.types.Operator):
    """Write the blend of the light sets at their current weights into the atlases' own files (HHD EXR, preview images, sidecar)"""

    bl_idname = "hhd.blend_light_sets"
    bl_label = "Blend"
    bl_options = {'REGISTER'}

    @classmethod
    def poll(cls, context):
        if not context.scene.hhd.light_sets:
            cls.poll_message_set("No light sets: bake a scene whose lights use Light Groups, or Refresh")
            return False
        return True

    def execute(self, context):
        scene = context.scene
        try:
            summary = light_sets.blend_atlases(light_sets.scene_atlases(scene), scene.hhd)
        except (BakeError, OSError) as exc:
            self.report({'ERROR'}, f"Blend failed: {exc}")
            return {'CANCELLED'}
        self.report({'INFO'}, summary)
        return {'FINISHED'}
