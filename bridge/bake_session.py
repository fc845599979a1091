"""One bake, split at the bpy boundary: read Blender → run the core pipeline → load the results.

`BakeSession(...)` reads everything the bake needs from Blender (main thread, no changes to the
scene); `run()` is pure core work (safe on a worker thread: it touches no bpy data) and writes
only the output files; `finish()` loads the written images into the .blend. A bake that is
cancelled or fails before `finish()` has changed nothing in the .blend and replaced no file.
"""

from __future__ import annotations

import os

import bpy

from ..core import bake as core_bake
from ..core import encoding as core_encoding
from ..core import progress as core_progress
from ..core.errors import BakeError
from ..core.files.lightmap_files import AtlasFiles
from . import collection_instances, denoiser, fingerprints, mesh_data, scene_data
from . import settings as bake_settings

DEFAULT_ATLAS = "Lightmap"
#: The shares of reading a scene (`BakeSession`): every object's triangles and fingerprint, the
#: receivers' surfaces, the atlases' layouts (measured on a 1.35M-triangle level: bench/end_to_end.py).
READ_SHARES = (0.4, 0.58, 0.02)


def target_objects(context, names: list[str] | None = None, settings=None) -> list:
    """Receivers: the named objects, else the target of `settings` (the scene's HHD settings, or
    an `Overridden` view of them: selected objects or a collection); an Empty that shows a
    collection stands for its Members (`collection_instances`), and a Member can be named as
    "<instancer>/<object>". Raises BakeError naming an object that does not exist or is neither
    a mesh nor a collection instance."""
    settings = context.scene.hhd if settings is None else settings
    if names:
        found = {n: collection_instances.find(n) for n in names}
        missing = [n for n, o in found.items() if o is None]
        if missing:
            raise BakeError(f"no object named {', '.join(repr(n) for n in missing)} in this .blend")
        wrong = [n for n, o in found.items() if o.type != 'MESH' and not collection_instances.shows_collection(o)]
        if wrong:
            raise BakeError(
                f"{', '.join(repr(n) for n in wrong)} is not a mesh object or a collection instance: only meshes "
                "get lightmaps"
            )
        return list(dict.fromkeys(collection_instances.receivers(found.values())))
    if settings.target == 'COLLECTION':
        if settings.target_collection is None:
            raise BakeError("Receivers is set to Collection but no collection is chosen")
        return collection_instances.receivers(settings.target_collection.all_objects)
    return collection_instances.receivers(context.selected_objects)


def output_folder(settings, override: str | None = None) -> str:
    """Absolute output folder: `override`, else the setting (relative to the .blend)."""
    path = override or settings.output_dir
    if path.startswith("//") and not bpy.data.is_saved:
        raise BakeError(
            f"the Output Folder '{path}' is relative to the .blend, which has not been saved: "
            "save the .blend or choose an absolute folder"
        )
    return os.path.normpath(bpy.path.abspath(path))


def atlas_groups(objects, settings) -> tuple[list[tuple[str, int, int, list]], list[str]]:
    """[(atlas name, width, height, objects)] from the last unwrap's record on each object
    (objects with lightmap UVs made elsewhere go into the default atlas at the scene resolution),
    and warnings for atlases only partly baked."""
    groups: dict[str, list] = {}
    for obj in objects:
        rec = obj.hhd
        name = rec.atlas or DEFAULT_ATLAS
        size = (rec.atlas_width, rec.atlas_height) if rec.atlas else (settings.resolution, settings.resolution)
        entry = groups.setdefault(name, [size, []])
        if entry[0] != size:
            raise BakeError(
                f"'{obj.name}' was unwrapped into atlas '{name}' at {size[0]}×{size[1]}, other objects "
                f"of that atlas at {entry[0][0]}×{entry[0][1]}: unwrap them together again"
            )
        entry[1].append(obj)
    warnings = []
    for name, (_, members) in groups.items():
        left_out = sorted(
            o.name for o in bpy.data.objects if o.type == 'MESH' and o.hhd.atlas == name and o not in members
        )
        if left_out:
            warnings.append(
                f"atlas '{name}' also holds {', '.join(repr(n) for n in left_out)}, not baked now: "
                "their texels in this bake's files are empty (bake them together)"
            )
    return [(name, size[0], size[1], members) for name, (size, members) in groups.items()], warnings


def instance_records(objects) -> dict:
    """{object name: {"mesh", "scale", "offset"}} of the objects among `objects` that are instances
    (a lightmap rectangle other than the identity, `core.unwrap.instances`): the sidecar's record."""
    out = {}
    for obj in objects:
        rect = mesh_data.lightmap_rect(obj)
        if rect != mesh_data.IDENTITY_RECT:
            out[obj.name] = {"mesh": obj.data.name, "scale": list(rect[:2]), "offset": list(rect[2:])}
    return out


def _check_receivers(objects, uv_layer: str) -> None:
    if not objects:
        raise BakeError("no mesh objects to bake: select the objects that should receive lightmaps")
    for obj in objects:
        if len(obj.data.polygons) == 0:
            raise BakeError(f"'{obj.name}' has no faces to bake")
        if uv_layer not in obj.data.uv_layers:
            raise BakeError(f"'{obj.name}' has no '{uv_layer}' UV layer: run Unwrap first")


def check_inward(context, objects: list[str] | None = None, settings=None) -> list[str]:
    """The receivers' faces that point into their own object (`core.bakepoints.inward`), without baking and
    without lightmap UVs: one message per object (the `inward_faces` action of `settings` named:
    the scene's HHD settings when None, or an `Overridden` view of them, which also choose the
    receivers), also kept in `scene.hhd.inward_report` for the panel."""
    from ..core.bakepoints import inward

    settings = context.scene.hhd if settings is None else settings
    receivers = target_objects(context, objects, settings)
    depsgraph = context.evaluated_depsgraph_get()
    lights = inward.light_points(scene_data.read_bake_scene(depsgraph))
    messages = []
    for obj in receivers:
        surface = mesh_data.read_shape(obj, depsgraph)
        if surface is None:
            continue
        for item in inward.find(surface, [obj.name], lights):
            messages.append(item.message(settings.inward_faces, done=False))
    set_inward_report(context.scene, messages)
    return messages


def set_inward_report(scene, messages: list[str]) -> None:
    """The panel's warning rows: `messages`, one per line."""
    scene.hhd.inward_report = "\n".join(messages)


def stitch_outcome(enabled: bool, atlas_warnings: list[list[str]]) -> str:
    """Summary word for a bake or re-encode: stitch setting `enabled`, each atlas's post-stage
    warnings (an atlas without a seams file is not stitched)."""
    if not enabled:
        return "not stitched"
    undone = sum(any("stitch: " in w for w in warnings) for warnings in atlas_warnings)
    if undone == 0:
        return "stitched"
    if undone == len(atlas_warnings):
        return "not stitched (see the warnings)"
    return f"stitched {len(atlas_warnings) - undone} of {len(atlas_warnings)} atlases (see the warnings)"


def _samples_text(trace) -> str:
    text = f"{trace.samples} samples"
    if trace.noise_target:
        text = f"≤ {text} (noise target {100 * trace.noise_target:g}%)"
    if trace.time_budget:
        text += f", time budget {trace.time_budget:g} s"
    return text


def _probes_text(grids) -> str:
    """', 2 probe volume(s) (1152 probes)' or '' without probe volumes."""
    if not grids:
        return ""
    return f", {len(grids)} probe volume(s) ({sum(g.count for g in grids)} probes)"


class BakeSession:
    """Everything one bake needs, read from Blender at construction (see the module doc).
    `threads`: worker threads (0 = every core); None takes the scene's Render > Performance >
    Threads (`settings.scene_threads`). `settings`: the scene's HHD settings, or an `Overridden`
    view of them (the CLI's options)."""

    def __init__(
        self,
        context,
        objects: list[str] | None = None,
        out_dir: str | None = None,
        threads: int | None = None,
        scheduler: str | None = None,
        settings=None,
        progress=None,
    ):
        settings = context.scene.hhd if settings is None else settings
        # `progress(fraction, message)`: how far the reading has come (a large level takes seconds)
        scene_part, surface_part, layout_part = core_progress.Tick(progress, name="reading the scene").split(
            READ_SHARES,
            ["reading the scene: objects", "reading the scene: receivers", "reading the scene: layouts"],
        )
        #: a Dask scheduler's address to bake on (core.farm), "" for this machine
        self.scheduler = (settings.scheduler if scheduler is None else scheduler).strip()
        self.farm_warnings: list[str] = []
        self.settings = bake_settings.scene_settings(context.scene, threads, settings)
        self.out_dir = output_folder(settings, out_dir)
        self.receivers = target_objects(context, objects, settings)
        _check_receivers(self.receivers, settings.uv_layer)
        groups, self.warnings = atlas_groups(self.receivers, settings)
        depsgraph = context.evaluated_depsgraph_get()
        cache = mesh_data.TextureCache()
        notes: list[str] = []
        # what the lighting depends on, for Bake Changed and the stale report (core.incremental),
        # read with the scene: each mesh evaluated once
        reader = fingerprints.Reader(groups, settings.uv_layer)
        self.scene = scene_data.read_bake_scene(depsgraph, scene_part, reader.visit)
        self.probe_grids = scene_data.read_probe_grids(depsgraph)
        notes += self.scene.notes
        self.atlases = []
        for (name, width, height, members), part in zip(groups, surface_part.split([1] * len(groups))):
            surface = mesh_data.read_surface(members, settings.uv_layer, depsgraph, cache, notes, part)
            self.atlases.append(
                core_bake.AtlasInput(name, width, height, surface, [o.name for o in members], instance_records(members))
            )
        self.warnings += list(dict.fromkeys(notes))
        # what `describe` and the sidecars say of the inputs, which `run` hands over (memory)
        self.occluder_triangles = int(len(self.scene.triangles))
        self.atlas_count = len(self.atlases)
        self.atlas_objects = [o for a in self.atlases for o in a.objects]
        layout_part.at(0.0)
        self.fingerprints = reader.finish(depsgraph)
        layout_part.show(1.0)
        self.pack = settings.pack_images
        self.blend = bpy.data.filepath
        self.scene_name = context.scene.name  # the bpy scene, for the light sets' weights after the bake
        self.results: list[core_bake.AtlasResult] = []

    def describe(self) -> str:
        n_occ = self.occluder_triangles
        return (
            f"{len(self.receivers)} receiver(s) in {self.atlas_count} atlas(es)"
            f"{_probes_text(self.probe_grids)}; {n_occ} occluder triangles; "
            f"{_samples_text(self.settings.trace)}, {self.settings.trace.bounces} bounces, "
            f"{'denoise' if self.settings.denoise else 'no denoise'}, "
            f"{'stitch' if self.settings.stitch_seams else 'no stitch'}, {self.settings.trace.threads} threads"
        )

    def run(self, progress=None, cancel=None, farm=None) -> list[core_bake.AtlasResult]:
        """The core bake and file output; touches no bpy data (worker-thread safe). `farm`: a
        connected `core.farm.Farm` to trace on (`core.bake.run`); without one, the session's
        `scheduler` (if any) is connected to here, for this bake."""
        if farm is None and self.scheduler:
            from ..core import farm as core_farm

            core_farm.Farm.check(self.settings.trace)  # a time budget is refused before connecting
            with core_farm.connect(self.scheduler) as connected:
                self.farm_warnings = list(connected.warnings)
                return self._run(progress, cancel, connected)
        return self._run(progress, cancel, farm)

    def _run(self, progress, cancel, farm) -> list[core_bake.AtlasResult]:
        extra = {
            "blend_file": self.blend,
            "receivers": self.atlas_objects,
            "occluder_triangles": self.occluder_triangles,
            "notes": self.warnings,
            "fingerprints": self.fingerprints.to_json(),
            "baked": dict.fromkeys(self.atlas_objects, self.fingerprints.to_json()["time"]),
        }
        # the atlases and the scene are handed over, no reference kept here nor in this frame
        # (the call takes its arguments' references): `core.bake.run` lets go of them as soon as
        # the bake no longer reads them, the scene before the last atlas's finishing (memory)
        self.results = core_bake.run(
            self._hand_over("atlases"),
            self._hand_over("scene"),
            self.settings,
            self.out_dir,
            progress=progress,
            cancel=cancel,
            extra_sidecar=extra,
            probe_grids=self.probe_grids,
            farm=farm,
        )
        return self.results

    def _hand_over(self, name: str):
        """The session's `name` input (atlases, scene), the session keeping no reference to it:
        a session runs once (`run`)."""
        value = getattr(self, name)
        if value is None:
            raise RuntimeError(f"this bake session has run already: its {name} were handed over")
        setattr(self, name, None)
        return value

    def finish(self) -> str:
        """Load the written images into the .blend; returns a one-line summary (the bake's
        warnings are `result_warnings`)."""
        atlases = [r for r in self.results if r.kind == "atlas"]
        for result in atlases:
            load_atlas_images(result.files, self.pack)
        texels = sum(r.texels for r in atlases)
        seconds = sum(sum(v for v in r.seconds.values()) for r in self.results)
        warnings = [r.warnings for r in self.results]
        denoised = denoiser.outcome(self.settings.denoise, warnings)
        stitched = stitch_outcome(self.settings.stitch_seams, warnings)
        sets = list(dict.fromkeys(name for r in self.results for name in r.sets))
        if sets:
            from .light_sets import sync_light_sets  # light_sets imports this module

            sync_light_sets(bpy.data.scenes[self.scene_name], sets)
        sets_text = f", light sets {', '.join(sets)}" if sets else ""
        return (
            f"Baked {texels} texels in {len(atlases)} atlas(es){_probes_text(self.probe_grids)} to {self.out_dir}, "
            f"{stitched}, {denoised}{sets_text} ({seconds:.1f} s: {', '.join(r.name for r in self.results)})"
        )

    @property
    def inward_warnings(self) -> list[str]:
        """The finished bake's messages about faces that point into their own object."""
        return [message for r in self.results for message in r.inward]

    @property
    def result_warnings(self) -> list[str]:
        """What the finished bake's post stages could not do, per atlas (e.g. no denoiser): the
        files are written all the same; the operator and the command line show these."""
        return self.farm_warnings + [w for r in self.results for w in r.warnings]


def load_atlas_images(files: AtlasFiles, pack: bool = False) -> list:
    """Load (or reload) an atlas's encoded EXRs (each encoding's file the folder holds: HHD, or the
    model the bake wrote) and its SH EXR as Non-Color images; external unless `pack`."""
    images = []
    encoded = [files.path(spec) for spec in core_encoding.documented_files() if spec.key not in ("sh", "texels")]
    for path in [p for p in dict.fromkeys(encoded) if p.exists()] + [files.sh]:
        image = next(
            (
                im
                for im in bpy.data.images
                if im.filepath and os.path.normpath(bpy.path.abspath(im.filepath)) == os.path.normpath(str(path))
            ),
            None,
        )
        if image is None:
            image = bpy.data.images.load(str(path), check_existing=False)
        else:
            image.reload()
        image.colorspace_settings.is_data = True
        if pack:
            image.pack()
        images.append(image)
    return images
