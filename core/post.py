"""Post stages: what runs on an atlas's texel images between tracing and encoding. No bpy.

A post stage (`PostStage`) takes the atlas's `encoding.TexelData` (SH, normals,
coverage as images) and a `check()` (raises to cancel) and returns new TexelData for the same
texels plus a record for the sidecar's `post` section. It works on images, not on the traced
texels, so the same stage runs on a fresh bake and on a re-encode from the raw SH file (which
keeps the SH as traced: a stage can be switched off later without tracing).

`stages_for(settings)` is the one place that decides which run, in order, from the pipeline
settings; `apply` runs them. A new post stage is a function here (or a module's) and a line in
`stages_for` (and the setting that switches it on in `bake.PipelineSettings`).
"""

from __future__ import annotations

from collections.abc import Callable

from .encoding import TexelData

#: (texel images, check) -> (new texel images, sidecar record). A record with "warning" is reported to the user.
PostStage = Callable[[TexelData, Callable[[], None]], tuple[TexelData, dict]]


def denoise_stage(library: str, threads: int) -> PostStage:
    """Open Image Denoise's lightmap filter on the SH (`core.denoise`), through the OIDN library at
    `library` ("" = none found). Where it cannot run (no library, no weights, OIDN failing) the
    SH passes through undenoised and the record says why: a bake never fails for its denoiser."""

    def denoise(data: TexelData, check: Callable[[], None]) -> tuple[TexelData, dict]:
        from . import denoise as _denoise  # loads numpy-only code; the OIDN library loads on first use

        try:
            denoiser = _denoise.denoiser_for(library, threads)
            out, report = _denoise.denoise_texels(data, denoiser, check)
        except _denoise.DenoiserError as e:
            return data, {"enabled": True, "applied": False, "warning": f"not denoised: {e}"}
        return out, {"enabled": True, "applied": True, "oidn_version": denoiser.version, **report.sidecar()}

    return denoise


def stages_for(settings) -> list[tuple[str, PostStage]]:
    """The post stages `settings` (a `bake.PipelineSettings`) switch on, as (name, stage) in the order they run."""
    stages = []
    if settings.denoise:
        stages.append(("denoise", denoise_stage(settings.denoiser_library, settings.trace.threads)))
    return stages


def apply(data: TexelData, settings, check: Callable[[], None] | None = None) -> tuple[TexelData, dict]:
    """`data` after every post stage of `settings`, in order, and the sidecar's `post` section:
    per stage its record ({"enabled": False} for the known stages that are off)."""
    records = {"denoise": {"enabled": False}}
    for name, stage in stages_for(settings):
        data, records[name] = stage(data, check or (lambda: None))
    return data, records


def warnings(records: dict) -> list[str]:
    """The records' warnings, each with its stage's name."""
    return [f"{name}: {r['warning']}" for name, r in records.items() if r.get("warning")]
