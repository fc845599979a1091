"""Operator: xatlas lightmap UVs for the selected mesh objects (`bpy.ops.hhd.unwrap()`).

Three steps: `read_objects` (main thread: the meshes into numpy, nothing changed), the core
unwrap (no bpy: any thread, cancellable), `write_objects` (main thread: the UV layers). From a
script or in background mode `execute` runs them in a row (a progress line on stdout when
headless); from the UI `invoke` runs the core unwrap on a thread with a progress bar, and Esc
cancels it before anything was written, so a cancelled unwrap leaves every mesh untouched.
"""

from dataclasses import dataclass, field

import bpy
from bpy.props import BoolProperty

from ..bridge import collection_instances, mesh_data
from ..core import unwrap as core_unwrap
from ..core.console import ConsoleProgress
from ..core.errors import BakeCancelled, BakeError
from ..core.progress import with_eta
from ..core.unwrap.data import padding_for_mips
from . import modal_work


class HHD_OT_unwrap(modal_work.ModalWork, bpy.types.Operator):
    """Chart and pack lightmap UVs with xatlas into the lightmap UV layer of the selected meshes"""

    bl_idname = "hhd.unwrap"
    bl_label = "Unwrap Lightmap UVs"
    bl_options = {'REGISTER', 'UNDO'}
    TITLE = "HHD unwrap"

    make_single_user: BoolProperty(
        name="Make Single User",
        default=False,
        description="Give linked duplicates their own mesh first; without it they share their mesh's lightmap UVs, "
        "each with its own rectangle in the atlas (instances)",
    )

    @classmethod
    def poll(cls, context):
        if modal_work.busy(cls):  # one bake or unwrap at a time
            return False
        if not any(o.type == 'MESH' or collection_instances.shows_collection(o) for o in context.selected_objects):
            cls.poll_message_set("Select one or more mesh objects or collection instances")
            return False
        return True

    def execute(self, context):
        settings = context.scene.hhd
        wm = context.window_manager
        console = ConsoleProgress() if bpy.app.background else None
        wm.progress_begin(0, 100)
        try:
            objects = collection_instances.receivers(context.selected_objects)
            outcome = unwrap_objects(
                objects,
                settings,
                self.make_single_user,
                with_eta(console) if console else (lambda f, _msg: wm.progress_update(int(100 * f))),
            )
        except BakeError as exc:
            outcome = exc
        finally:
            wm.progress_end()
            if console:
                console.close()
        return self._done(context, outcome)

    def _done(self, context, outcome):
        """Report (summary, warnings) or the BakeError that ended the unwrap."""
        if isinstance(outcome, BakeCancelled):
            self.report({'WARNING'}, "Unwrap cancelled: no mesh was changed")
            return {'CANCELLED'}
        if isinstance(outcome, BakeError):
            self.report({'ERROR'}, str(outcome))
            return {'CANCELLED'}
        summary, warnings = outcome
        for w in warnings:
            self.report({'WARNING'}, w)
        context.scene.hhd.unwrap_summary = summary
        self.report({'INFO'}, summary)
        return {'FINISHED'}

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            objects = collection_instances.receivers(context.selected_objects)
            self._job = read_objects(objects, context.scene.hhd, self.make_single_user)
        except BakeError as exc:
            self.report({'ERROR'}, str(exc))
            return {'CANCELLED'}
        return self._start_work(context, lambda progress, cancel: compute(self._job, with_eta(progress), cancel))

    def _work_done(self, context, result, error):
        if error is not None and not isinstance(error, BakeError):
            raise error
        try:
            outcome = error or write_objects(self._job, context.scene.hhd, result)
        except BakeError as exc:
            outcome = exc
        return self._done(context, outcome)


@dataclass
class UnwrapJob:
    """What `read_objects` read: the objects, their core meshes (world space) and loop indices
    (T, 3) per triangle corner, the core settings, whether linked duplicates must be made single
    user when writing, each mesh's loop count (to notice a mesh edited meanwhile), and warnings
    found while reading."""

    objects: list
    meshes: list
    loops: list
    settings: core_unwrap.UnwrapSettings
    make_single_user: bool
    loop_counts: list
    warnings: list = field(default_factory=list)


def read_objects(objects, settings, make_single_user=False) -> UnwrapJob:
    """Read `objects` for an unwrap with the scene settings (main thread; changes nothing).
    Linked duplicates (objects sharing a mesh) become instances (`core.unwrap.instances`: one layout
    of the mesh, a rectangle of the atlas per object), or with make_single_user are given their
    own meshes when the result is written."""
    mesh_data.refuse_linked(objects)
    shared = mesh_data.shared_meshes(objects)
    instanced = {} if make_single_user else shared
    warnings = [
        f"{', '.join(repr(n) for n in names)} share the mesh '{mesh}' with objects unwrapped now but "
        "are not unwrapped now: their lightmap UVs change too, so unwrap and bake them together"
        for mesh, names in mesh_data.outside_users(objects).items()
    ]
    read = [mesh_data.read_unwrap_mesh(o, o.data.name if o.data.name in instanced else None) for o in objects]
    padding = settings.padding or padding_for_mips(settings.mip_levels)
    core_settings = core_unwrap.UnwrapSettings(
        resolution=settings.resolution,
        texel_density=settings.texel_density or None,
        padding=padding,
        per_object=settings.atlas_mode == 'PER_OBJECT',
    )
    return UnwrapJob(
        list(objects),
        [m for m, _ in read],
        [loops for _, loops in read],
        core_settings,
        bool(shared) and make_single_user,
        [len(o.data.loops) for o in objects],
        warnings,
    )


def compute(job: UnwrapJob, progress=None, cancel=None) -> core_unwrap.UnwrapResult:
    """The core unwrap of a job (no bpy: any thread); cancel() True raises BakeCancelled."""
    return core_unwrap.unwrap(job.meshes, job.settings, progress, cancel)


def unwrap_objects(objects, settings, make_single_user=False, progress=None, cancel=None):
    """Unwrap `objects` with the scene settings; returns (summary line, warnings). Nothing is
    changed if it raises (BakeCancelled once cancel() returns True)."""
    job = read_objects(objects, settings, make_single_user)
    return write_objects(job, settings, compute(job, progress, cancel))


def write_objects(job: UnwrapJob, settings, result):
    """Write the unwrap `result` of `job` into the objects' lightmap UV layers (main thread);
    returns (summary line, warnings)."""
    _check_unchanged(job)
    if job.make_single_user:
        mesh_data.make_single_user(job.objects)
    objects = job.objects
    warnings = job.warnings + list(result.warnings)
    instancers = {o.instancer.name for o in objects if isinstance(o, collection_instances.Member)}
    others = {
        o.hhd.atlas
        for o in bpy.data.objects
        if o.hhd.atlas and ((o.type == 'MESH' and o not in objects) or (o.type == 'EMPTY' and o.name not in instancers))
    }
    names = atlas_names(
        [o.name for o in objects], [o.atlas for o in result.objects], others, result.part, result.instanced
    )
    written = set()
    for obj, loops, ouv in zip(objects, job.loops, result.objects):
        if obj.data.name not in written:  # an instanced mesh's layer once: the same for each instance
            mesh_data.write_uv_layer(obj, settings.uv_layer, loops, ouv.layer)
            written.add(obj.data.name)
        if isinstance(obj, collection_instances.Member):
            obj.store(names[ouv.atlas], result.atlas_sizes[ouv.atlas], ouv.inner, ouv.outer)
            continue
        obj.hhd.atlas = names[ouv.atlas]
        obj.hhd.atlas_width, obj.hhd.atlas_height = result.atlas_sizes[ouv.atlas]
        obj.hhd.lightmap_rect = ouv.instance or mesh_data.IDENTITY_RECT
    sizes = ", ".join(f"{w}×{h}" for w, h in result.atlas_sizes)
    used = ", ".join(f"{100 * u:.0f}%" for u in result.utilisation)
    per_object = ", ".join(f"{o.name}: {o.texels:.0f}" for o in result.objects)
    atlases = (
        f"atlas {sizes}"
        if len(result.atlas_sizes) == 1
        else f"{len(result.atlas_sizes)} atlases ({', '.join(names[a] for a in sorted(names))}) {sizes}"
    )
    summary = (
        f"{len(objects)} object(s), {result.charts} charts, {atlases}, {used} used; texels per object: {per_object}"
    )
    return summary, warnings


def _check_unchanged(job: UnwrapJob) -> None:
    """Raise BakeError if an object was deleted or its mesh edited since it was read."""
    for obj, count in zip(job.objects, job.loop_counts):
        try:
            same = obj.type == 'MESH' and len(obj.data.loops) == count
        except ReferenceError:
            raise BakeError("an object was deleted while unwrapping: unwrap again") from None
        if not same:
            raise BakeError(f"'{obj.name}' was edited while unwrapping: unwrap again")


def atlas_names(
    objects: list[str],
    atlas_of: list[int],
    taken: set[str] = frozenset(),
    part: list[int] | None = None,
    instanced: list[bool] | None = None,
) -> dict[int, str]:
    """File-name stems per atlas index: "Lightmap_instances" for an atlas of instances (linked
    duplicates, `core.unwrap.instances`), "Lightmap" for an atlas shared by several objects (or the
    only atlas), "Lightmap_1", "Lightmap_2", … for the further atlases a full shared atlas spilled
    into (`part[atlas]` > 0, see `core.unwrap.UnwrapResult.part`), "Lightmap_<object>" for an
    object's own atlas (characters unsafe in file names replaced by '_'). A name already given,
    or used by other objects' atlases (`taken`), gets a number, so a second unwrap of other
    objects never makes their bakes overwrite each other's files."""
    members: dict[int, list[str]] = {}
    for name, atlas in zip(objects, atlas_of):
        members.setdefault(atlas, []).append(name)
    out, used = {}, set(taken)
    for atlas in sorted(members):
        names = members[atlas]
        if instanced is not None and instanced[atlas]:
            name = "Lightmap_instances"
        elif part is not None and part[atlas] > 0:
            name = f"Lightmap_{part[atlas]}"
        elif len(names) > 1 or len(members) == 1 or (part is not None and _spill_head(atlas, part)):
            name = "Lightmap"
        else:
            name = "Lightmap_" + "".join(c if c.isalnum() or c in "-_." else "_" for c in names[0])
        base, k = name, 2
        while name in used:
            name, k = f"{base}_{k}", k + 1
        out[atlas] = name
        used.add(name)
    return out


def _spill_head(atlas: int, part: list[int]) -> bool:
    """Whether `atlas` is the first of a run of atlases one group spilled into."""
    return atlas + 1 < len(part) and part[atlas + 1] == 1
