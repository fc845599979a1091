"""Operators: show / hide the baked lighting in EEVEE (`bpy.ops.hhd.preview_show()` / `preview_hide()`)."""

from pathlib import Path

import bpy

from ..bridge import bake_session
from ..core.errors import BakeError
from ..core.files.lightmap_files import AtlasFiles
from ..core.files.preview import kind_of, sampled, sh_previews
from ..shaders import preview
from .bake import receivers_poll


def atlas_files_of(objects, settings) -> dict:
    """{object name: AtlasFiles} for baked objects; raises BakeError naming one without a bake,
    one whose model the preview mode cannot show (`core.files.preview.kind_of`: HHD, AHD and
    Scalar need an HHD file, L1/L2 read the raw SH file of any atlas, Encoded shows the atlas's
    own model), or whose bake lacks the images that mode samples."""
    folder = Path(bake_session.output_folder(settings))
    mode = settings.preview_mode
    out = {}
    for obj in objects:
        name = obj.hhd.atlas or bake_session.DEFAULT_ATLAS
        files = AtlasFiles(folder, name)
        if not files.sidecar.is_file():
            raise BakeError(f"'{obj.name}' has no bake in {folder} (atlas '{name}'): bake it first")
        model = preview.model_of(files)
        kind = kind_of(mode, model)
        if kind is None:  # an HHD mode on another model (its HHD preview images, if any, are stale)
            raise BakeError(
                f"atlas '{name}' is encoded as {model}: choose Preview Encoded (or L1/L2 SH from the raw SH file), "
                "or re-encode the atlas as HHD (Re-encode, or `encode --model hhd`)"
            )
        if kind in ("L1", "L2"):
            sh_previews(files)  # written when first shown, not by the bake
        if not all(files.preview_image(ch.preview).is_file() for ch in sampled(kind)):
            raise BakeError(
                f"atlas '{name}' ({model}) lacks the preview images of its {kind} layers in {files.preview}: "
                "re-encode it (Re-encode, or `encode`) to write them"
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
