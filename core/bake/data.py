"""What a bake takes and gives: the atlases in (`AtlasInput`), the pipeline's settings
(`PipelineSettings`), one written atlas or probe volume out (`AtlasResult`), and the cancel check
every job of a bake shares. No bpy."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import cast

from .. import tracer
from ..bakepoints import SurfaceTriangles, inward
from ..encoding import EncoderSettings
from ..errors import BakeCancelled
from ..files import lightmap_files


@dataclass
class AtlasInput:
    """One atlas to bake: its name (file stem), size in texels, the receiving triangles and the
    names of the objects they belong to (`surface.object_index` indexes `objects`); instances:
    {object name: {"mesh", "scale", "offset"}} of the objects that share their mesh's lightmap
    UVs (`core.unwrap.instances`; the surface's UVs are already atlas UVs), recorded in the sidecar.
    Only the bake points read the surface: past them a bake's jobs carry its atlases without it
    (`without_surface`: memory), as a farm's finishing task does."""

    name: str
    width: int
    height: int
    surface: SurfaceTriangles
    objects: list[str]
    instances: dict = field(default_factory=dict)

    def without_surface(self) -> AtlasInput:
        """This atlas with its surface None, for what follows its bake points (nothing reads it)."""
        return replace(self, surface=cast(SurfaceTriangles, None))


@dataclass(frozen=True)
class PipelineSettings:
    """trace: the tracer's settings; encoder: the encoding and its options (`core.encoding`);
    denoise: run the denoise post stage (`core.post`), through the Open Image Denoise library at
    `denoiser_library` (the bpy side finds Blender's; "" = none: the bake is then undenoised, with
    a warning); stitch_seams: run the stitch post stage (`core.post.seams`) after it, so a smooth
    surface split between charts reads the same on both sides of the split. A bake writes the
    atlas's seams file either way, so a re-encode can switch stitching on or off. inward_faces:
    what to do with faces that point into their own object (`core.bakepoints.inward`: OPEN_SIDE bakes them
    from the side light reaches, AS_MODELLED as they are, with a warning; REFUSE: InwardFacesRefused).

    A value (frozen): the Blender side builds it once per bake from the scene's settings, or
    from them overridden by the command line's options (`bridge.settings`); the samples per
    pass, the pass count and the thread count are `trace`'s (`tracer.BakeSettings`)."""

    trace: tracer.BakeSettings = field(default_factory=tracer.BakeSettings)
    encoder: EncoderSettings = field(default_factory=EncoderSettings)
    denoise: bool = False
    denoiser_library: str = ""
    stitch_seams: bool = True
    inward_faces: str = inward.OPEN_SIDE

    def resolved(self) -> PipelineSettings:
        """These settings with the trace's thread count resolved (`BakeSettings.resolved`)."""
        return replace(self, trace=self.trace.resolved())


@dataclass
class AtlasResult:
    """One written atlas (kind "atlas") or probe volume (kind "probes": texels are its probes):
    seconds per stage; warnings: what a post stage could not do (e.g. no denoiser), and `inward`;
    sets: its light sets (`core.light_sets`; none without light groups); inward: one message per
    object with faces that point into it (`core.bakepoints.inward`)."""

    name: str
    files: lightmap_files.AtlasFiles
    texels: int
    rays: int
    seconds: dict
    warnings: list[str] = field(default_factory=list)
    sets: tuple[str, ...] = ()
    kind: str = "atlas"
    inward: list[str] = field(default_factory=list)


def atlas_result(atlas: AtlasInput, out_dir, info: dict) -> AtlasResult:
    """The AtlasResult of one atlas written into `out_dir` from `finish_atlas`'s summary."""
    files = lightmap_files.AtlasFiles(Path(out_dir), atlas.name)
    return AtlasResult(atlas.name, files, info["texels"], info["rays"], info["seconds"], info["warnings"], info["sets"])


def _check_cancel(cancel) -> None:
    if cancel is not None and cancel():
        raise BakeCancelled("bake cancelled")
