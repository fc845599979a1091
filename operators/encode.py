"""Operator: re-encode baked lightmaps with the current encoder settings (`bpy.ops.hhd.encode()`).

Reads each receiver atlas's SH and texel EXRs from the output folder and writes a new HHD EXR and
sidecar (atomically); no tracing. The loaded images are reloaded.
"""

import os
from pathlib import Path

import bpy

from ..bridge import bake_session
from ..core import bake as core_bake
from ..core.errors import BakeError
from ..core.lightmap_files import AtlasFiles
from .bake import receivers_poll


class HHD_OT_encode(bpy.types.Operator):
    """Encode the last bake again from its SH EXR with the current encoder settings (no tracing)"""

    bl_idname = "hhd.encode"
    bl_label = "Re-encode"
    bl_options = {'REGISTER'}

    @classmethod
    def poll(cls, context):
        return receivers_poll(cls, context)

    def execute(self, context):
        settings = context.scene.hhd
        try:
            objects = bake_session.target_objects(context)
            summary = reencode_objects(objects, settings, threads=bake_session.scene_threads(context.scene))
        except (BakeError, OSError) as exc:
            self.report({'ERROR'}, f"Re-encode failed: {exc}")
            return {'CANCELLED'}
        self.report({'INFO'}, summary)
        return {'FINISHED'}


def reencode_objects(objects, settings, out_dir: str | None = None, threads: int = 0) -> str:
    """Re-encode the atlases of `objects` found in the output folder with `threads` workers
    (0 = every core); returns a summary line."""
    if not objects:
        raise BakeError("no mesh objects to re-encode: select baked objects")
    folder = bake_session.output_folder(settings, out_dir)
    groups, _ = bake_session.atlas_groups(objects, settings)
    encoder = bake_session.encoder_settings(settings)
    done = []
    for name, *_ in groups:
        files = AtlasFiles(Path(folder), name)
        seconds = core_bake.reencode(files, encoder, threads)
        bake_session.load_atlas_images(files, settings.pack_images)
        done.append(f"'{name}' {seconds:.1f} s")
    return f"Re-encoded ({encoder.model}, {encoder.direction}, {encoder.ambient} ambient): {', '.join(done)}"


class HHD_OT_open_output(bpy.types.Operator):
    """Open the output folder in the system's file browser"""

    bl_idname = "hhd.open_output"
    bl_label = "Open Output Folder"

    @classmethod
    def poll(cls, context):
        try:
            folder = bake_session.output_folder(context.scene.hhd)
        except BakeError as exc:
            cls.poll_message_set(str(exc))
            return False
        if not os.path.isdir(folder):
            cls.poll_message_set(f"'{folder}' does not exist yet: bake first")
            return False
        return True

    def execute(self, context):
        bpy.ops.wm.path_open(filepath=bake_session.output_folder(context.scene.hhd))
        return {'FINISHED'}
