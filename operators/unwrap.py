"""Operator: xatlas lightmap UVs for the selected mesh objects (`bpy.ops.hhd.unwrap()`)."""
import bpy
from bpy.props import BoolProperty

from ..core import unwrap as core_unwrap
from ..core.errors import BakeError
from . import mesh_data


class HHD_OT_unwrap(bpy.types.Operator):
    """Chart and pack lightmap UVs with xatlas into the lightmap UV layer of the selected meshes"""
    bl_idname = "hhd.unwrap"
    bl_label = "Unwrap Lightmap UVs"
    bl_options = {'REGISTER', 'UNDO'}

    make_single_user: BoolProperty(
        name="Make Single User", default=False,
        description="Give linked duplicates their own mesh first (they cannot share lightmap UVs)")

    @classmethod
    def poll(cls, context):
        if not mesh_data.target_meshes(context.selected_objects):
            cls.poll_message_set("Select one or more mesh objects")
            return False
        return True

    def execute(self, context):
        settings = context.scene.hhd
        objects = mesh_data.target_meshes(context.selected_objects)
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            summary, warnings = unwrap_objects(objects, settings, self.make_single_user,
                                               lambda f, _msg: wm.progress_update(int(100 * f)))
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        finally:
            wm.progress_end()
        for w in warnings:
            self.report({'WARNING'}, w)
        settings.unwrap_summary = summary
        self.report({'INFO'}, summary)
        return {'FINISHED'}


def unwrap_objects(objects, settings, make_single_user=False, progress=None):
    """Unwrap `objects` with the scene settings; returns (summary line, warnings)."""
    shared = mesh_data.shared_meshes(objects)
    if shared and not make_single_user:
        mesh, names = next(iter(shared.items()))
        raise BakeError(f"{', '.join(repr(n) for n in names)} share the mesh '{mesh}': one lightmap UV "
                        "layer cannot give them separate texels. Make them single user (Object > Relations > "
                        "Make Single User > Object & Data), or unwrap with 'Make Single User'")
    if shared:
        mesh_data.make_single_user(objects)
    read = [mesh_data.read_unwrap_mesh(o) for o in objects]
    padding = settings.padding or core_unwrap.padding_for_mips(settings.mip_levels)
    result = core_unwrap.unwrap(
        [m for m, _ in read],
        core_unwrap.UnwrapSettings(resolution=settings.resolution, texel_density=settings.texel_density or None,
                                   padding=padding, per_object=settings.atlas_mode == 'PER_OBJECT'),
        progress)
    warnings = list(result.warnings)
    others = {o.hhd.atlas for o in bpy.data.objects if o.type == 'MESH' and o not in objects and o.hhd.atlas}
    names = atlas_names([o.name for o in objects], [o.atlas for o in result.objects], others)
    for obj, (_, loops), ouv in zip(objects, read, result.objects):
        mesh_data.write_uv_layer(obj, settings.uv_layer, loops, ouv.uv)
        obj.hhd.atlas = names[ouv.atlas]
        obj.hhd.atlas_width, obj.hhd.atlas_height = result.atlas_sizes[ouv.atlas]
    sizes = ", ".join(f"{w}×{h}" for w, h in result.atlas_sizes)
    used = ", ".join(f"{100 * u:.0f}%" for u in result.utilisation)
    per_object = ", ".join(f"{o.name}: {o.texels:.0f}" for o in result.objects)
    summary = (f"{len(objects)} object(s), {result.charts} charts, atlas {sizes}, {used} used; "
               f"texels per object: {per_object}")
    return summary, warnings


def atlas_names(objects: list[str], atlas_of: list[int], taken: set[str] = frozenset()) -> dict[int, str]:
    """File-name stems per atlas index: "Lightmap" for an atlas shared by several objects (or the
    only atlas), "Lightmap_<object>" for an object's own atlas (characters unsafe in file names
    replaced by '_'); a name other objects' atlases (`taken`) already use gets a number, so a
    second unwrap of other objects never makes their bakes overwrite each other's files."""
    members: dict[int, list[str]] = {}
    for name, atlas in zip(objects, atlas_of):
        members.setdefault(atlas, []).append(name)
    out = {}
    for atlas, names in members.items():
        if len(names) > 1 or len(members) == 1:
            out[atlas] = "Lightmap"
        else:
            out[atlas] = "Lightmap_" + "".join(c if c.isalnum() or c in "-_." else "_" for c in names[0])
        base, k = out[atlas], 2
        while out[atlas] in taken:
            out[atlas], k = f"{base}_{k}", k + 1
    return out
