"""A subset bake's merge into the atlas's files: the re-traced texels written into the previous
bake's, then the raw files, the post stages and the encoder on the region of the touched texels
(or the whole atlas), only the touched texels of each file replaced. No bpy."""

from __future__ import annotations

import functools

import numpy as np

from .. import encoding, post
from ..encoding.stage import WINDOW_MARGIN
from ..errors import BakeCancelled, FullBakeNeeded
from ..files import exr, lightmap_files
from ..post.denoise.layout import label_charts

#: A subset bake's merge runs its post stages and encoder on the region of the touched texels
#: (`merge_region`) unless it holds more than this share of the atlas's chart texels: then on the
#: whole atlas (measured: bench/results/incremental_merge.md).
WINDOW_SHARE_MAX = 0.6


def _merge(old, fresh, texels: np.ndarray):
    """`old` (a bake's TexelData, whole atlas) with the texels `texels` (flat) of `fresh` (the
    subset's, whole atlas) written into it: SH, n_v, coverage and noise."""
    h, w = old.coverage.shape

    def put(a, b):
        flat_a, flat_b = a.reshape((h * w,) + a.shape[2:]), b.reshape((h * w,) + b.shape[2:])
        flat_a[texels] = flat_b[texels]

    put(old.sh, fresh.sh)
    put(old.normal, fresh.normal)
    put(old.coverage, fresh.coverage)
    if old.noise is not None and fresh.noise is not None:
        put(old.noise, fresh.noise)
    return old


def _merge_files(staging, files, data, sidecar, settings, atlas_seams, mask, *, update, cancel) -> list[str]:
    """Raw files → post stages → encode of the merged `data` (whole atlas), each file staged with
    only the `mask` texels taken from it (`_stage_merged`). The raw files are of the whole atlas;
    the post stages and the encoder run on the region of the `mask` texels (`_region_encode`),
    or on the whole atlas (as a re-encode) where the region would hold more than
    WINDOW_SHARE_MAX of its chart texels or cannot give the same fill. The sidecar's
    `incremental.merge` says which ran, and why."""

    def check():
        if cancel is not None and cancel():
            raise BakeCancelled("bake cancelled")

    fill = data.fill()
    tables = {}
    with encoding.raw_files(data, fill) as images_of:
        for key, (spec, images) in images_of.items():
            tables[key] = _stage_merged(staging, files, spec, images, mask)
            check()
    doc = dict(sidecar)
    # the staged raw SH file holds `data`'s baked texels: a denoiser failing half-way reads them back
    raw_sh = functools.partial(lightmap_files.read_sh, staging.staged(files.sh))
    region = _region_encode(data, fill, settings, atlas_seams, mask, check, raw_sh)
    if isinstance(region, str):
        data, records = post.apply(data, settings, seams=atlas_seams, raw_sh=raw_sh)
        encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False)
        encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, records)
        doc["stats"] = encoded.stats
        merge: dict = {"over": "atlas", "why": region}
    else:
        encoded, records, merge = region
    check()
    for key, (encoded_spec, layers) in encoded.files.items():
        tables[key] = _stage_merged(staging, files, encoded_spec, layers, mask)
    doc.update(update)
    doc["incremental"] = {**doc.get("incremental", {}), "merge": merge}
    doc["channels"] = {**doc.get("channels", {}), **tables}
    doc["post"] = records
    staging.write_json(files.sidecar, doc, indent=2, ensure_ascii=False)
    return post.warnings(records)


#: Texels around the touched texels and their charts that a region merge's stages see
#: (`merge_region`): an almost empty atlas's window margin (`encoding.stage.WINDOW_MARGIN`:
#: beyond the dilation's reach from a stitched gutter texel and the denoiser's page margin). The
#: denoiser needs no more: it filters each chart with its own texels only, and the region holds
#: every touched chart whole (`_region_encode`).
WINDOW_HALO = WINDOW_MARGIN
#: Side in texels of the tiles whose touched texels' bounding boxes, grown by WINDOW_HALO, make
#: the region.
WINDOW_TILE = 64


def merge_region(held: np.ndarray, halo: int = WINDOW_HALO, tile: int = WINDOW_TILE) -> np.ndarray:
    """The region `(H, W)` bool of an atlas the merge's stages run on: per `tile` × `tile` tile
    holding texels of `held` `(H, W)` bool (the touched texels and their charts), the bounding
    box of those grown by `halo` texels (clipped to the atlas). Every `held` texel lies in it
    with at least `halo` texels of it around (or the atlas's edge)."""
    h, w = held.shape
    ty, tx = -(-h // tile), -(-w // tile)
    padded = np.zeros((ty * tile, tx * tile), bool)
    padded[:h, :w] = held
    tiles = padded.reshape(ty, tile, tx, tile)
    rows_any, cols_any = tiles.any(axis=3), tiles.any(axis=1)  # (ty, tile, tx), (ty, tx, tile)
    region = np.zeros((h, w), bool)
    for i, j in zip(*np.nonzero(rows_any.any(axis=1))):
        r, c = np.flatnonzero(rows_any[i, :, j]), np.flatnonzero(cols_any[i, j])
        y0, x0 = max(i * tile + r[0] - halo, 0), max(j * tile + c[0] - halo, 0)
        region[y0 : i * tile + r[-1] + 1 + halo, x0 : j * tile + c[-1] + 1 + halo] = True
    return region


def _region_encode(data, fill, settings, atlas_seams, mask, check, raw_sh):
    """The post stages and encoder of `_merge_files` on `data` (the merged atlas; spent: its
    texels outside the region are emptied in place) with every texel outside `merge_region`
    empty (no chart, no value): their cost follows the region's charts and texels, not the
    atlas's, and on the `mask` texels they give the whole atlas's values: the encoder, the fill
    (checked: every `mask` texel fills from the same texel) and the stitch (the same seams and
    unknowns) exactly; the denoiser filters each touched chart whole and alone, its pages
    (shared with other charts, each page's exposure and energy scale) hold fewer charts than
    the whole atlas's: bench/results/incremental_merge.md measures the difference. Returns (the
    EncodedAtlas, the post records, the sidecar's `incremental.merge`), or why the whole atlas
    must run instead (then `data` is untouched). The sidecar's stats stay the last full
    encode's (the region's are in `incremental.merge`). `raw_sh`: `post.apply`'s."""
    labels, n = label_charts(data.coverage != 0.0)  # the denoiser's charts
    reads = _fill_reads(fill)[mask.reshape(-1)]
    seeds = mask.copy()  # the touched texels and the texels they fill from (a buried texel's: far in its chart)
    seeds.reshape(-1)[reads[reads >= 0]] = True
    touched = np.zeros(n + 1, bool)
    touched[labels[seeds] + 1] = True
    touched[0] = False  # texels outside charts
    region = merge_region(seeds | touched[labels + 1], WINDOW_HALO, WINDOW_TILE)
    del labels
    covered = data.coverage != 0.0
    share = np.count_nonzero(covered & region) / float(max(int(np.count_nonzero(covered)), 1))
    if share > WINDOW_SHARE_MAX:
        return f"the region holds {100 * share:.0f}% of the atlas's chart texels (over {100 * WINDOW_SHARE_MAX:.0f}%)"
    outside = ~region
    coverage = data.coverage[outside]
    data.coverage[outside] = 0.0
    flat = mask.reshape(-1)
    if not np.array_equal(_fill_reads(fill)[flat], _fill_reads(data.fill())[flat]):
        data.coverage[outside] = coverage
        return "a touched texel fills from beyond the region"  # (a buried texel far into a cut chart)
    del coverage
    data.sh[outside] = 0.0
    data.normal[outside] = 0.0
    if data.noise is not None:
        data.noise[outside] = np.nan
    check()
    data, records = post.apply(data, settings, seams=atlas_seams, raw_sh=raw_sh)  # as the whole atlas's
    check()
    encoded = encoding.encode_atlas(data, encoding.for_settings(settings.encoder), raw=False)
    encoded = post.stitch_encoded(encoded, data.coverage, settings, atlas_seams, records)
    texels = int(np.count_nonzero(region))
    merge = {"over": "region", "texels": texels, "share": share, "halo": WINDOW_HALO, "stats": encoded.stats}
    return encoded, records, merge


def _fill_reads(fill) -> np.ndarray:
    """`(H·W,)` int64: what `fill.apply(..., keep_black=True)` puts in each texel: its own value
    (its index), its source's (that index), the mean of the sources (-1) or 0 (-2: black)."""
    out = np.arange(fill.shape[0] * fill.shape[1], dtype=np.int64)
    out[fill.empty] = fill.source
    out[fill.black] = -2
    return out


def _stage_merged(staging, files, spec, images: dict, mask: np.ndarray) -> dict:
    """Stage one file of `spec`: the previous file's channels with the `mask` texels (rows
    bottom-up) taken from `images` (the merged atlas's, bottom-up); a channel stored as half
    before and needing float now (or the reverse) is stored as float, so no old value changes.
    Its preview images follow from the merged channels (but for PREVIEWS_ON_DEMAND). Returns its
    channel table."""
    channels = lightmap_files.exr_channels(spec, images)
    path = files.path(spec)
    old, _ = exr.read(path)
    rows = exr.to_exr_rows(mask, copy=False)
    merged = {}
    for name, new in channels.items():
        before = old.get(name)
        if before is None or before.shape != new.shape:
            raise FullBakeNeeded(f"{path} lacks channel {name} or is of another size: bake all")
        dtype = np.float32 if np.float32 in (before.dtype, new.dtype) else np.float16
        out = before.astype(dtype)  # half → float is exact
        out[rows] = np.asarray(new).astype(dtype)[rows]
        merged[name] = out
    attributes = {
        "hhdFormat": lightmap_files.FORMAT,
        "hhdFormatVersion": lightmap_files.FORMAT_VERSION,
        "hhdAtlas": files.name,
    }
    exr.write_file(staging.stage(path), merged, attributes)
    if spec.key not in lightmap_files.PREVIEWS_ON_DEMAND:
        lightmap_files.stage_preview(staging, files, spec, merged)
    return lightmap_files.channel_table(spec, merged)
