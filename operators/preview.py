"""Operators: show / hide the baked lighting in EEVEE (`bpy.ops.hhd.preview_show()` / `preview_hide()`)."""

from pathlib import Path

import bpy

from ..bridge import bake_session
from ..core.encoding.preview import sampled
from ..core.errors import BakeError
from ..core.lightmap_files import AtlasFiles, read_sidecar
from ..shaders import preview
from .bake import receivers_poll


def atlas_files_of(objects, settings) -> dict:
    """{object name: AtlasFiles} for baked objects; raises BakeError naming one without a bake, or
    whose bake lacks the images the preview mode samples (an atlas encoded in a model the preview
    does not show, say SG9, still previews as L1/L2 SH from its raw SH file)."""
    folder = Path(bake_session.output_folder(settings))
    out = {}
    for obj in objects:
        name = obj.hhd.atlas or bake_session.DEFAULT_ATLAS
        files = AtlasFiles(folder, name)
        if not files.sidecar.is_file():
            raise BakeError(f"'{obj.name}' has no bake in {folder} (atlas '{name}'): bake it first")
        if not all(files.preview_image(ch.preview).is_file() for ch in sampled(settings.preview_mode)):
            model = read_sidecar(files.sidecar).get("encoder", {}).get("model", "?")
            raise BakeError(
                f"atlas '{name}' is encoded as {model}: the EEVEE preview shows HHD and AHD, or L1/L2 SH from "
                "the raw SH file; choose Preview L1 SH or L2 SH, or re-encode the atlas as HHD (Re-encode, "
                "or `encode --model hhd`)"
            )
        out[obj.name] = files
    return out


class HHD_OT_preview_show(bpy.types.Operator):
    """Show the baked lightmaps on the receivers' materials in EEVEE, decoded as a game engine would"""

    bl_idname = "hhd.preview_show"
    bl_label = "Show Preview"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return receivers_poll(cls, context)

    def execute(self, context):
        settings = context.scene.hhd
        try:
            objects = bake_session.target_objects(context)
            if not objects:
                raise BakeError("no mesh objects selected")
            files = atlas_files_of(objects, settings)
            notes = preview.show(objects, files, settings.preview_mode, settings.uv_layer, settings.preview_self_bounce)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        for note in notes:
            self.report({'WARNING'}, note)
        self.report({'INFO'}, f"Preview ({settings.preview_mode}) on {len(objects)} object(s)")
        return {'FINISHED'}


class HHD_OT_preview_hide(bpy.types.Operator):
    """Remove the preview and restore every material exactly as it was"""

    bl_idname = "hhd.preview_hide"
    bl_label = "Hide Preview"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        if not any(preview.RECORD in m for m in bpy.data.materials):
            cls.poll_message_set("No preview is shown")
            return False
        return True

    def execute(self, context):
        restored = preview.hide()
        self.report({'INFO'}, f"Preview removed from {restored} material(s)")
        return {'FINISHED'}
