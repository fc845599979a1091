"""Post stages: what runs on an atlas's texel images between tracing and encoding (the stage's
package: `denoise/` the denoiser, `seams/` the seams and their stitching; this module runs them).
No bpy.

A post stage (`PostStage`) takes the atlas's `encoding.TexelData` (SH, normals,
coverage as images) and a `check()` (raises to cancel) and returns new TexelData for the same
texels plus a record for the sidecar's `post` section. It works on images, not on the traced
texels, so the same stage runs on a fresh bake and on a re-encode from the raw SH file (which
keeps the SH as traced: a stage can be switched off later without tracing).

`stages_for(settings, seams)` is the one place that decides which run, in order, from the
pipeline settings; `apply` runs them. A new post stage is a function here (or a module's in this package) and a
line in `stages_for` (and the setting that switches it on in `bake.PipelineSettings`).

Order: denoise, then stitch. The denoiser filters chart by chart, so it leaves (and can widen) a
step where a smooth surface crosses from one chart to another; stitching (`seams`) runs on
the filtered SH so the seams the encoder sees are closed, and once more on the encoded layers
(`stitch_encoded`, after the encode stage) for the step the non-linear encoding leaves. The seams are geometry, not images: a
bake finds them on its receivers' mesh, a re-encode reads them from the atlas's seams file
(`lightmap_files.AtlasFiles.seams`); `None` (a bake older than the file) skips stitching with a
warning.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, cast

import numpy as np

from .. import progress
from ..encoding import EncodedAtlas, TexelData
from ..memory import trim_heap
from ..stages import PlacedImage, Window

if TYPE_CHECKING:
    from .seams.geometry import Seams

#: (texel images, check) -> (new texel images, sidecar record). A record with "warning" is reported to the user.
PostStage = Callable[[TexelData, Callable[[], None]], tuple[TexelData, dict]]


def denoise_stage(library: str, threads: int, raw_sh: Callable[[], np.ndarray] | None = None) -> PostStage:
    """Open Image Denoise's lightmap filter on the SH (`denoise.pages`), through the OIDN library at
    `library` ("" = none found). Where it cannot run (no library, no weights, OIDN failing) the
    SH passes through undenoised and the record says why: a bake never fails for its denoiser.
    The SH is denoised into the TexelData's own image, nothing of it kept (`apply`); OIDN
    failing half-way puts it back from `raw_sh()` (`pages.denoise_texels`)."""

    def denoise(data: TexelData, check: Callable[[], None]) -> tuple[TexelData, dict]:
        from .denoise import filtering, oidn, pages  # loads numpy-only code; the OIDN library loads on first use

        try:
            denoiser = filtering.denoiser_for(library, threads)
            out, report = pages.denoise_texels(data, denoiser, check, raw_sh)
        except oidn.DenoiserError as e:
            return data, {"enabled": True, "applied": False, "warning": f"not denoised: {e}"}
        return out, {"enabled": True, "applied": True, "oidn_version": denoiser.version, **report.sidecar()}

    return denoise


#: Why an atlas is not stitched when its seams are unknown (a bake made before seams files existed).
NO_SEAMS = "not stitched: this bake has no seams file (bake again to stitch its seams)"


def stitch_stage(seams: Seams | None, threads: int) -> PostStage:
    """Least-squares seam stitching of the SH (`seams.stitching.stitch`, on `threads` workers) along
    `seams`, the atlas's seam sample pairs. `None` (no seams file: an older bake) passes the SH
    through unstitched, with a warning in the record. Its second half runs after encoding
    (`stitch_encoded`). The stitched texels are written into the TexelData's own images (`apply`)."""

    def stitch(data: TexelData, check: Callable[[], None]) -> tuple[TexelData, dict]:
        if seams is None:
            return data, {"enabled": True, "applied": False, "warning": NO_SEAMS}
        from .seams import stitching

        out, record = stitching.stitch(data, seams, check, threads)
        return out, _finite({"enabled": True, "applied": True, **record})

    return stitch


#: The encodings whose layers `stitch_encoded` closes the seams of (HHD/AHD: I_z, w_a and the
#: direction are not linear in the SH). The coefficient encodings are projections of the stitched
#: SH (linear: SH, HL2, H-basis; the SG fits nearly so), so their layers are left as encoded.
ENCODED_STITCH_MODELS = ("hhd", "ahd")
ENCODED_STITCH_SKIPPED = "the encoding's layers come from the stitched SH (no second stitch for this model)"


def stitch_encoded(
    encoded: EncodedAtlas,
    coverage: np.ndarray,
    settings,
    seams: Seams | None,
    records: dict,
    check: Callable[[], None] | None = None,
) -> EncodedAtlas:
    """The stitch stage's second half, on the encoding's layers after `encoding.encode_atlas`:
    the encoding is not linear in the SH, so it leaves a small step along seams the SH stitch
    closed; `seams.encoded_stitch.stitch_encoded` closes it in the encoded layers. Runs only where the SH
    stitch ran (`records`, `apply`'s, says so) and adds its record as `records["stitch"]["encoded"]`.
    `coverage` `(H, W)`: the atlas's (`TexelData.coverage`). `encoded` is this stage's
    (`core.memory`): the stitched texels are written into its own images."""
    if not settings.stitch_seams or seams is None or not records.get("stitch", {}).get("applied"):
        return encoded
    if encoded.settings.get("model", "hhd") not in ENCODED_STITCH_MODELS:
        records["stitch"]["encoded"] = {"enabled": False, "why": ENCODED_STITCH_SKIPPED}
        return encoded
    from .seams import encoded_stitch

    window, placed = _windowed(encoded)
    out, record = encoded_stitch.stitch_encoded(placed, seams, coverage, check, settings.trace.threads, window)
    records["stitch"]["encoded"] = _finite(record)
    return out if window is None else _placed(out, encoded)


def _windowed(encoded: EncodedAtlas) -> tuple[Window | None, EncodedAtlas]:
    """The window of `encoded`'s encoding file (its images `stages.PlacedImage`s: an almost
    empty atlas's, `TexelData.window`) and the atlas with that file's window images; (None,
    `encoded`) for whole images."""
    key = encoded.encoding_file.key
    spec, images = encoded.files[key]
    first = next(iter(images.values()), None)
    if not isinstance(first, PlacedImage):
        return None, encoded
    inner = {name: image.inner for name, image in images.items()}
    return first.window, replace(encoded, files={**encoded.files, key: (spec, inner)})


def _placed(out: EncodedAtlas, like: EncodedAtlas) -> EncodedAtlas:
    """`out`'s encoding file (window images) placed in the atlas as `like`'s are (`_windowed`)."""
    key = out.encoding_file.key
    spec, images = out.files[key]
    around = like.files[key][1]
    placed = {name: replace(cast(PlacedImage, around[name]), inner=image) for name, image in images.items()}
    # a PlacedImage stands in for the atlas's image (the writers take either: `exr.write_file`)
    return replace(out, files={**out.files, key: (spec, cast(dict[str, np.ndarray], placed))})


def _finite(record):
    """`record` with every non-finite float (a seam ratio over a zero interior step) as None: the
    sidecar stays strict JSON."""
    if isinstance(record, dict):
        return {k: _finite(v) for k, v in record.items()}
    if isinstance(record, list):
        return [_finite(v) for v in record]
    if isinstance(record, float) and not math.isfinite(record):
        return None
    return record


def stages_for(
    settings, seams: Seams | None = None, raw_sh: Callable[[], np.ndarray] | None = None
) -> list[tuple[str, PostStage]]:
    """The post stages `settings` (a `bake.PipelineSettings`) switch on, as (name, stage) in the
    order they run; `seams`: the atlas's seams for the stitch stage (None: unknown); `raw_sh`:
    the denoise stage's (`apply`'s)."""
    stages = []
    if settings.denoise:
        stages.append(("denoise", denoise_stage(settings.denoiser_library, settings.trace.threads, raw_sh)))
    if settings.stitch_seams:
        stages.append(("stitch", stitch_stage(seams, settings.trace.threads)))
    return stages


def apply(
    data: TexelData,
    settings,
    check: Callable[[], None] | None = None,
    seams: Seams | None = None,
    raw_sh: Callable[[], np.ndarray] | None = None,
) -> tuple[TexelData, dict]:
    """`data` after every post stage of `settings`, in order, and the sidecar's `post` section:
    per stage its record ({"enabled": False} for the known stages that are off). `seams`: the
    atlas's seam sample pairs (`seams.geometry.Seams`; None: unknown, stitching is then skipped with
    a warning). `check` may be a
    `core.progress.Tick`: each stage gets its part of it (by `progress.POST_COSTS`), named after
    the stage ("denoise 'Lightmap'"), which a stage may report to (`Tick.at`) or just call.

    `data` is the stages' (`core.memory`): the denoiser and the stitch write into its images
    and keep nothing of what they overwrite (a caller that needs them afterwards hands over
    `memory.keep(data)`). `raw_sh()`: `data.sh` as handed over, read back `(H, W, 9, 3)` (the
    whole atlas's: the raw SH file a bake writes before its post stages, the one a re-encode
    read): a denoiser failing half-way puts the SH back from it and the atlas goes on
    undenoised; without it, that failure raises."""
    records = {"denoise": {"enabled": False}, "stitch": {"enabled": False}}
    tick = progress.ticker(check)
    stages = stages_for(settings, seams, raw_sh)
    names = [f"{name} {tick.name}".strip() for name, _ in stages]
    parts = tick.split([progress.POST_COSTS.get(name, progress.COST_DENOISE) for name, _ in stages], names)
    for part, (name, stage) in zip(parts, stages):
        part.at(0.0)
        data, records[name] = stage(data, part)
        trim_heap()  # what the stage's threads freed, before the next one allocates (memory)
    return data, records


def warnings(records: dict) -> list[str]:
    """The records' warnings, each with its stage's name."""
    return [f"{name}: {r['warning']}" for name, r in records.items() if r.get("warning")]
