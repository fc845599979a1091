"""The subset bake (`bake_subset`): bake points of some receivers of an atlas, traced with the
bake's settings and seed, merged into the atlas's files (`merge`); refused (`FullBakeNeeded`)
where the files cannot take them. No bpy."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import encoding, tracer
from ..errors import BakeCancelled, FullBakeNeeded
from ..files import exr, lightmap_files
from .fingerprints import _now, _receivers_of
from .merge import _merge, _merge_files


@dataclass
class SubsetResult:
    """One atlas re-traced in part: its name, the objects re-traced, texels re-traced, texels
    written (re-traced + seam partners + their fill), all texels of the atlas's bake, seconds per
    stage."""

    name: str
    objects: list[str]
    texels: int
    written: int
    atlas_texels: int
    seconds: dict
    warnings: list[str] = field(default_factory=list)


def check_settings(sidecar: dict, settings, name: str) -> None:
    """FullBakeNeeded when the bake settings the texels depend on differ from the last bake's."""
    was = sidecar.get("bake", {})
    now = asdict(settings.trace)
    for key in ("samples", "pass_samples", "bounces", "noise_target", "light_sets"):
        if key in was and was[key] != now[key]:
            raise FullBakeNeeded(
                f"atlas '{name}' was baked with {key} = {was[key]}, the settings now give {now[key]}: "
                "bake all (a part baked otherwise would not match the rest)"
            )
    encoder = dict(encoding.for_settings(settings.encoder).settings)
    for key, value in sidecar.get("encoder", {}).items():
        if key in encoder and encoder[key] != value:
            raise FullBakeNeeded(
                f"atlas '{name}' was encoded with {key} = {value!r}, the settings now give {encoder[key]!r}: "
                "bake all, or re-encode first"
            )
    records = sidecar.get("post", {})
    for key, on in (("denoise", settings.denoise), ("stitch", settings.stitch_seams)):
        if key in records and bool(records[key].get("enabled")) != bool(on):
            raise FullBakeNeeded(
                f"atlas '{name}' was baked with {key} {'on' if records[key].get('enabled') else 'off'}, "
                f"it is {'on' if on else 'off'} now: bake all, or re-encode first"
            )


def _subset_surface(surface, rows: np.ndarray):
    """The SurfaceTriangles of `surface`'s triangles `rows` (object indices kept)."""
    out = replace(
        surface,
        positions=surface.positions[rows],
        normals=surface.normals[rows],
        uv=surface.uv[rows],
        object_index=surface.object_index[rows],
        albedo=surface.albedo[rows],
    )
    for key in ("texture_index", "texture_uv", "polygon"):
        value = getattr(surface, key)
        if value is not None:
            setattr(out, key, value[rows])
    return out


def touched_mask(
    texels: np.ndarray, shape: tuple[int, int], atlas_seams, baked: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """The texels a subset bake writes back and the seam samples it stitches: (`(H, W)` bool,
    rows bottom-up; `(S,)` bool or None without seams). `texels`: flat indices (y·W + x)
    re-traced; `atlas_seams` (`seams.Seams` or None): a seam sample whose bilinear footprint (the
    2×2 texels around each side's position) holds a marked texel marks both sides' footprints
    (stitching moves both), repeated until no sample is added (a chain of seams sharing texels is
    stitched together); `baked` `(H, W)` bool, the dilation sources: the texels outside them whose
    nearest source (`dilate.nearest_source`) is marked are marked too (their fill changes)."""
    from .. import dilate
    from ..encoding.stage import DILATE_RINGS

    h, w = shape
    mask = np.zeros(h * w, bool)
    mask[texels] = True
    hit = None
    if atlas_seams is not None and len(atlas_seams):
        feet = [_footprint(atlas_seams.a, h, w), _footprint(atlas_seams.b, h, w)]
        hit = np.zeros(len(atlas_seams), bool)
        while True:
            now = mask[feet[0]].any(axis=1) | mask[feet[1]].any(axis=1)
            if (now == hit).all():
                break
            hit = now
            for foot in feet:
                mask[foot[hit].reshape(-1)] = True
    source = dilate.nearest_source(baked, DILATE_RINGS).reshape(-1)
    outside = np.flatnonzero(~baked.reshape(-1))
    reached = source[outside] >= 0
    mask[outside[reached]] |= mask[source[outside[reached]]]
    return mask.reshape(h, w), hit


def _footprint(pos: np.ndarray, h: int, w: int) -> np.ndarray:
    """(S, 4) flat indices of the 2×2 texels a bilinear read at texel-space `pos` (S, 2) takes
    (texel (i, j) centred at (i + ½, j + ½)), clamped to the atlas."""
    x0 = np.floor(pos[:, 0] - 0.5).astype(np.int64)
    y0 = np.floor(pos[:, 1] - 0.5).astype(np.int64)
    xs = np.clip(np.stack([x0, x0 + 1, x0, x0 + 1], 1), 0, w - 1)
    ys = np.clip(np.stack([y0, y0, y0 + 1, y0 + 1], 1), 0, h - 1)
    return ys * w + xs


def bake_subset(
    atlases: list,
    only: dict[str, list[str]],
    scene,
    settings,
    out_dir,
    record: Callable[[str, list[str]], dict] | None = None,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> list[SubsetResult]:
    """Re-trace the receivers `only[atlas name]` of each atlas of `atlases` (`bake.AtlasInput`,
    every object of the atlas: the layout) and write their texels into the atlas's files in
    `out_dir` (module doc). `record(atlas, objects)` gives the sidecar keys to set (the
    fingerprints and the objects' bake times). Raises FullBakeNeeded (nothing written) when an
    atlas has no earlier bake, its files are of another size or other receivers, a re-traced
    texel lies outside the earlier bake's charts (the layout changed), or the settings differ."""
    from ..bake import points as bake_points

    settings = settings.resolved()
    exr.set_threads(settings.trace.threads)
    chosen = [(a, only[a.name]) for a in atlases if only.get(a.name)]
    if not chosen:
        raise FullBakeNeeded("nothing to bake: none of the named objects is a receiver of a baked atlas")
    out_dir = Path(out_dir)
    previous = [_previous(a, names, settings, out_dir) for a, names in chosen]  # refuse before any work
    atlases_in, found, scene = bake_points.check_inward([a for a, _ in chosen], scene, settings.inward_faces)
    ray_scene = bake_points.ray_scene_of(scene)
    results = []
    report = progress or (lambda f, m: None)
    with exr.Staging() as staging:
        for k, ((_, names), atlas, sidecar) in enumerate(zip(chosen, atlases_in, previous)):
            base, share = k / len(chosen), 1.0 / len(chosen)
            results.append(
                _bake_atlas(
                    staging,
                    atlas,
                    names,
                    sidecar,
                    scene,
                    ray_scene,
                    settings,
                    out_dir,
                    record=record,
                    report=lambda f, m, base=base, share=share: report(base + share * f, m),
                    cancel=cancel,
                )
            )
        if cancel is not None and cancel():
            raise BakeCancelled("bake cancelled")
        staging.commit()
    report(1.0, "written")
    return results


def _previous(atlas, names: list[str], settings, out_dir: Path) -> dict:
    """The atlas's last sidecar, after checking a subset bake can go into its files."""
    files = lightmap_files.AtlasFiles(out_dir, atlas.name)
    if not files.sidecar.is_file() or not files.sh.is_file() or not files.texels.is_file():
        raise FullBakeNeeded(f"atlas '{atlas.name}' has no earlier bake in {out_dir}: bake all first")
    sidecar = lightmap_files.read_sidecar(files.sidecar)
    if (sidecar.get("width"), sidecar.get("height")) != (atlas.width, atlas.height):
        raise FullBakeNeeded(
            f"atlas '{atlas.name}' was baked at {sidecar.get('width')}×{sidecar.get('height')}, it is "
            f"{atlas.width}×{atlas.height} now (unwrapped again): bake all"
        )
    before = set(_receivers_of(sidecar))
    if before != set(atlas.objects):
        added, gone = sorted(set(atlas.objects) - before), sorted(before - set(atlas.objects))
        raise FullBakeNeeded(
            f"atlas '{atlas.name}' holds other receivers than at its last bake (new: {', '.join(added) or 'none'}; "
            f"gone: {', '.join(gone) or 'none'}): bake all"
        )
    missing = [n for n in names if n not in atlas.objects]
    if missing:
        raise FullBakeNeeded(f"{', '.join(missing)}: not in atlas '{atlas.name}'")
    check_settings(sidecar, settings, atlas.name)
    return sidecar


def _bake_atlas(staging, atlas, names, sidecar, scene, ray_scene, settings, out_dir, *, record, report, cancel):
    """Re-trace `names` of one atlas and stage its merged files (`bake_subset`)."""
    from .. import light_sets as _ls
    from ..bake import points as bake_points

    t0 = time.perf_counter()
    files = lightmap_files.AtlasFiles(out_dir, atlas.name)
    indices = [atlas.objects.index(n) for n in names]
    rows = np.flatnonzero(np.isin(atlas.surface.object_index, indices))
    part = replace(atlas, surface=_subset_surface(atlas.surface, rows))
    report(0.0, f"bake points of {', '.join(names)}")
    points = bake_points.points_of(part, ray_scene, settings.trace.threads, cancel)
    t_points = time.perf_counter() - t0
    old = lightmap_files.read_texel_data(files)
    h, w = old.coverage.shape
    if not (old.coverage.reshape(-1)[points.texel] != 0.0).all():
        raise FullBakeNeeded(
            f"atlas '{atlas.name}': {', '.join(names)} cover texels outside the last bake's charts "
            "(the layout changed: unwrapped again?): bake all"
        )
    set_names = [e["name"] for e in sidecar.get("light_sets", [])]
    t = time.perf_counter()
    traced = tracer.bake(
        points,
        scene,
        settings.trace,
        progress=lambda f, m: report(0.8 * f, m),
        cancel=cancel,
        ray_scene=ray_scene,
        compact=True,
    )
    if list(traced.sets) != set_names:
        raise FullBakeNeeded(
            f"atlas '{atlas.name}' was baked with light sets {set_names or 'none'}, the scene now has "
            f"{list(traced.sets) or 'none'}: bake all"
        )
    t_trace = time.perf_counter() - t
    t = time.perf_counter()
    report(0.8, "merging into the atlas's files")
    atlas_seams = lightmap_files.read_seams(files, (h, w))
    fresh = encoding.TexelData.from_points(points, traced.sh, noise=traced.noise())
    merged = _merge(old, fresh, points.texel)
    mask, hit = touched_mask(points.texel, (h, w), atlas_seams, merged.baked)
    if atlas_seams is not None and hit is not None:
        atlas_seams = atlas_seams.select(hit)  # stitch the seams of the touched charts only
    when = _now()
    keys = record(atlas.name, names) if record else {}
    baked = {**sidecar.get("baked", {}), **{n: when for n in names}}
    total = int((merged.coverage != 0.0).sum())  # before the merge empties texels outside its region
    update = {
        **keys,
        "baked": baked,
        "incremental": {
            "time": when,
            "objects": list(names),
            "texels_traced": int(len(points.texel)),
            "texels_written": int(mask.sum()),
            "rays": int(traced.rays),
        },
    }
    warnings = _merge_files(staging, files, merged, sidecar, settings, atlas_seams, mask, update=update, cancel=cancel)
    for k, set_name in enumerate(set_names):
        set_files = lightmap_files.AtlasFiles(out_dir, _ls.set_atlas_name(atlas.name, set_name), atlas.name)
        set_sidecar = lightmap_files.read_sidecar(set_files.sidecar)
        set_fresh = encoding.TexelData.from_points(points, traced.light_set(k).sh, noise=traced.light_set(k).noise())
        set_merged = _merge(lightmap_files.read_texel_data(set_files), set_fresh, points.texel)
        warnings += _merge_files(
            staging, set_files, set_merged, set_sidecar, settings, atlas_seams, mask, update=update, cancel=cancel
        )
    seconds = {"bake_points": t_points, "trace": t_trace, "merge": time.perf_counter() - t}
    return SubsetResult(atlas.name, list(names), int(len(points.texel)), int(mask.sum()), total, seconds, warnings)
