"""Operator: re-encode baked lightmaps with the current encoder settings (`bpy.ops.hhd.encode()`).

Reads each receiver atlas's SH and texel EXRs from the output folder and writes a new HHD EXR and
sidecar (atomically); no tracing. The SH EXR holds the SH as traced, so the current Denoise and
Stitch Seams settings decide whether the new encoding is of the denoised and stitched SH (stitching
reads the atlas's seams file; a bake made before those files is encoded unstitched, with a
warning). The loaded images are reloaded.
"""

import os
import traceback
from pathlib import Path

import bpy

from ..bridge import bake_session, denoiser
from ..bridge import settings as bake_settings
from ..core import bake as core_bake
from ..core.errors import BakeError
from ..core.files.lightmap_files import AtlasFiles
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
            summary, warnings = reencode_objects(objects, settings, bake_settings.scene_settings(context.scene))
        except BakeError as exc:  # a damaged or mismatched bake: the message names the file and the fix
            self.report({'ERROR'}, f"Re-encode failed: {exc}")
            return {'CANCELLED'}
        except OSError as exc:
            self.report(
                {'ERROR'}, f"Re-encode failed: cannot write {exc.filename or 'the files'}: {exc.strerror or exc}"
            )
            return {'CANCELLED'}
        except Exception as exc:  # a bug: the traceback goes to the console, the artist gets one line
            traceback.print_exc()
            self.report({'ERROR'}, f"Re-encode failed (a bug, please report it with the console's traceback): {exc}")
            return {'CANCELLED'}
        for warning in warnings:  # e.g. no denoiser: encoded undenoised
            self.report({'WARNING'}, warning)
        self.report({'INFO'}, summary)
        return {'FINISHED'}


def reencode_objects(
    objects, settings, pipeline: core_bake.PipelineSettings, out_dir: str | None = None
) -> tuple[str, list[str]]:
    """Re-encode the atlases of `objects` found in the output folder with the settings value
    `pipeline` (`bridge.settings.scene_settings`, as a bake builds it): its encoder, denoised if
    `pipeline.denoise` (through Blender's OIDN library it names), stitched if
    `pipeline.stitch_seams`, with its trace's thread count. `settings` (the scene's HHD settings
    or the CLI's `Overridden` view) give what is not the pipeline's: the output folder (`out_dir`
    else theirs), the atlases' sizes and whether the images are packed. Returns a summary line
    and the warnings (what a post stage could not do, e.g. no denoiser, no seams file)."""
    if not objects:
        raise BakeError("no mesh objects to re-encode: select baked objects")
    folder = bake_session.output_folder(settings, out_dir)
    groups, _ = bake_session.atlas_groups(objects, settings)
    encoder = pipeline.encoder
    done, warnings = [], []
    for name, *_ in groups:
        files = AtlasFiles(Path(folder), name)
        seconds, atlas_warnings = core_bake.reencode(
            files,
            encoder,
            pipeline.trace.threads,
            denoise=pipeline.denoise,
            denoiser_library=pipeline.denoiser_library,
            stitch_seams=pipeline.stitch_seams,
        )
        bake_session.load_atlas_images(files, settings.pack_images)
        done.append(f"'{name}' {seconds:.1f} s")
        warnings.append(atlas_warnings)
    denoised = denoiser.outcome(pipeline.denoise, warnings)
    stitched = bake_session.stitch_outcome(pipeline.stitch_seams, warnings)
    summary = (
        f"Re-encoded ({encoder.model}, {encoder.direction}, {encoder.ambient} ambient, {stitched}, {denoised}): "
        f"{', '.join(done)}"
    )
    return summary, [w for ws in warnings for w in ws]


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
