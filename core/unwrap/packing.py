"""Packing: the cached charts of a group of meshes into one atlas at a fixed density, or fitted to
a fixed resolution; spilling them over several atlases when one cannot hold them; each
object's UVs in its atlas. No bpy."""

from __future__ import annotations

from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from . import xatlas_packing
from .data import MAX_RESOLUTION, AtlasFull, ObjectUV
from .worker_runs import _cores, _run_worker, waiting

#: Packed atlases kept for re-unwrapping the same charts with the same settings: at most this
#: many, and this many bytes of UVs (24 per triangle).
PACK_CACHE_ENTRIES, PACK_CACHE_BYTES = 8, 128 << 20
#: Fitting (`xatlas_packing.fit`) below this many triangles packs one density a round, in one
#: child (starting a child costs more than such a pack; one a round needs the fewest packs);
#: above, two a round, side by side in two children, or one after the other in one on one core.
#: The triangles alone choose how many a round, so the densities packed, and the atlas, are the
#: same on any machine.
ONE_CHILD_TRIANGLES = 50_000


_PACKED: OrderedDict[tuple, dict] = OrderedDict()  # (keys, settings) → pack result


#: Share of an atlas that the padded chart boxes of one spilled group may take at zero density
#: (padding alone) when choosing how many atlases to start with: the rest is for the charts.
SPILL_PADDING_SHARE = 0.5


def _spill(indices, pack, charts, resolution, density, padding):
    """[(mesh indices, pack result)]: one atlas if the charts of `indices` fit one (`pack`
    raises AtlasFull when not), else the objects spread over the fewest atlases that each fit:
    objects are dealt largest first to the least loaded atlas (by padded chart-box area), so
    every object stays whole in one atlas. An object that alone does not fit is an error."""
    try:
        return [(indices, pack(indices))]
    except AtlasFull:
        if len(indices) == 1:
            raise
    boxes = [xatlas_packing.chart_boxes([(c.chart, c.corner, c.uv)])[1] for c in (charts[i] for i in indices)]
    count = _first_spill_count(boxes, resolution, density, padding)
    while True:
        packed = []
        for part in _deal(indices, boxes, count, resolution, density, padding):
            try:
                packed.append((part, pack(part)))
            except AtlasFull:
                if len(part) == 1:  # one object alone: more atlases cannot help
                    raise
                break
        else:
            return packed
        count += 1


def _area_density(boxes, resolution, density, padding):
    """Texels per metre at which to weigh the objects' chart boxes: the given density, or the
    one at which all the boxes would fill one resolution² atlas (none if padding alone does)."""
    if density is not None:
        return density
    t = xatlas_packing.box_density(np.concatenate(boxes), resolution, padding, 1.0)
    return t or 0.0


def _first_spill_count(boxes, resolution, density, padding) -> int:
    """Atlases to try first: enough that each holds its share of the padded boxes at the density
    the objects are weighed at, and that padding alone takes at most SPILL_PADDING_SHARE of each."""
    q = 2.0 * padding + 2.0
    all_boxes = np.concatenate(boxes)
    size = resolution if density is None else MAX_RESOLUTION
    padding_only = len(all_boxes) * q * q / (SPILL_PADDING_SHARE * size * size)
    t = density if density is not None else 0.0
    at_density = xatlas_packing.box_area(all_boxes, padding, t) / (size * size)
    return int(min(len(boxes), max(2, np.ceil(max(padding_only, at_density)))))


def _deal(indices, boxes, count, resolution, density, padding):
    """`indices` dealt into `count` groups, heaviest object first to the lightest group, by the
    area of their padded chart boxes; each group keeps the input order."""
    t = _area_density(boxes, resolution, density, padding)
    weight = [xatlas_packing.box_area(b, padding, t) for b in boxes]
    load = [0.0] * count
    parts: list[list[int]] = [[] for _ in range(count)]
    for k in sorted(range(len(indices)), key=lambda k: -weight[k]):
        g = min(range(count), key=load.__getitem__)
        load[g] += weight[k]
        parts[g].append(k)
    return [[indices[k] for k in sorted(p)] for p in parts if p]


# --- packing ---
def _pack(meshes, charts, keys, resolution, density, padding, progress=None, cancel=None):
    """Pack the charts of `meshes` into one atlas (see `xatlas_packing.pack`); returns the
    worker's result dict plus "texels_per_metre" and "packs" (pack runs). A fixed density is
    packed once into an atlas of the size it needs; a fixed resolution is fitted by `_fit`.
    The same charts packed with the same settings before in this session are not packed again."""
    cache_key = (tuple(keys), int(resolution), density, int(padding))
    if cache_key in _PACKED:
        _PACKED.move_to_end(cache_key)
        return dict(_PACKED[cache_key], packs=0)
    if density is not None:
        units = density * xatlas_packing.PACK_UNITS_PER_TEXEL
        beat = (lambda s: progress(0.0, f"xatlas: packing at {density:.4g} texels/m, {s:.0f} s")) if progress else None
        result = waiting(lambda: _pack_at([density], charts, meshes, 0, padding, units, cancel), beat)[0]
        if max(result["width"], result["height"]) > MAX_RESOLUTION:
            raise AtlasFull(
                f"texel density {density:g}/m needs a {result['width']}×{result['height']} atlas for "
                f"{_names(meshes)}, larger than {MAX_RESOLUTION}²: lower the density or give some "
                "objects their own atlas"
            )
        result.update(texels_per_metre=density, packs=1)
    else:
        result = _fit(meshes, charts, resolution, padding, progress, cancel)
    _PACKED[cache_key] = result
    while len(_PACKED) > 1 and (
        len(_PACKED) > PACK_CACHE_ENTRIES
        or sum(sum(u.nbytes for u in r["uv"]) for r in _PACKED.values()) > PACK_CACHE_BYTES
    ):
        _PACKED.popitem(last=False)
    return result


def _fit(meshes, charts, resolution, padding, progress=None, cancel=None):
    """Pack at the largest density found that fits one resolution² atlas (`xatlas_packing.fit`):
    one density a round when the charts' meshes have ONE_CHILD_TRIANGLES or fewer, else two; in
    one child when one a round or one core, else driven from here with the two packed side by
    side in parallel children (the same densities, the same atlas)."""
    payload = [(c.chart, c.corner, c.uv) for c in charts]
    _, boxes = xatlas_packing.chart_boxes(payload)
    q, fill = 2 * padding + 2, min(xatlas_packing.FIRST_FILL)
    if xatlas_packing.box_density(boxes, resolution, padding, fill) is None:
        raise AtlasFull(
            f"{_names(meshes)}: {len(boxes)} charts with padding {padding} need at least "
            f"{len(boxes) * q * q:.0f} texels for their padding alone, more than {fill:.0%} of a "
            f"{resolution}² atlas: raise the resolution, lower the padding, or give some objects "
            "their own atlas"
        )
    triangles = sum(len(m.triangles) for m in meshes)
    fills = tuple(xatlas_packing.FIRST_FILL)
    if triangles <= ONE_CHILD_TRIANGLES:
        fills = (float(np.mean(fills)),)
    shown = [0.0, "xatlas: packing"]  # the last progress reported: repeated while a child packs

    def report(fraction, message):
        shown[:] = [fraction, message]
        if progress:
            progress(fraction, message)

    beat = (lambda s: progress(shown[0], f"{shown[1]}, {s:.0f} s")) if progress else None
    if _cores() < 2 or len(fills) == 1:
        job = {"task": "fit", "charts": payload, "resolution": int(resolution), "padding": int(padding), "fills": fills}
        result = waiting(lambda: _run_worker(job, [m.name for m in meshes], triangles, cancel), beat)
    else:

        def pack_at(densities, units):
            return waiting(lambda: _pack_at(densities, charts, meshes, resolution, padding, units, cancel), beat)

        result = xatlas_packing.fit(pack_at, boxes, resolution, padding, fills, report)
    if not result["fits"]:
        raise AtlasFull(
            f"could not fit the {len(boxes)} charts of {_names(meshes)} into one {resolution}² atlas "
            f"with padding {padding}: raise the resolution, lower the padding, or give some objects "
            "their own atlas"
        )
    return result


def _pack_at(densities, charts, meshes, resolution, padding, units, cancel=None):
    """Worker pack results, one per density (texels per metre), packed in parallel children."""
    payload = [(c.chart, c.corner, c.uv) for c in charts]
    names = [m.name for m in meshes]
    triangles = sum(len(m.triangles) for m in meshes)

    def run(density):
        job = {
            "task": "pack",
            "charts": payload,
            "texels_per_metre": float(density),
            "resolution": int(resolution),
            "padding": int(padding),
            "units": float(units),
        }
        return _run_worker(job, names, triangles, cancel)

    if len(densities) == 1:
        return [run(densities[0])]
    with ThreadPoolExecutor(max_workers=len(densities)) as pool:
        return list(pool.map(run, densities))


def _names(meshes) -> str:
    shown = ", ".join(f"'{m.name}'" for m in meshes[:5])
    return shown + (f" and {len(meshes) - 5} more" if len(meshes) > 5 else "")


def _upright(atlas) -> bool:
    """Whether the charts xatlas packed span more rows than columns of its atlas (`_object_uv`
    turns such an atlas a quarter)."""
    placed = [u[u.any(axis=(1, 2))].reshape(-1, 2) for u in atlas["uv"]]  # placed triangles' corners
    corners = np.concatenate(placed).astype(np.float64) if placed else np.zeros((0, 2))
    if not len(corners):
        return False
    corners *= [atlas["width"], atlas["height"]]
    span = corners.max(axis=0) - corners.min(axis=0)
    return bool(span[1] > span[0])


def _object_uv(mesh, atlas, k, atlas_index, w, h, turn=False):
    """ObjectUV of mesh k of a packed `atlas` in the final w × h atlas. The worker's UVs are
    normalised by xatlas's atlas size; they are rescaled to the final size, and with `turn`
    (xatlas's atlas taller than wide; w, h are already the turned sizes) turned a quarter,
    (u, v) → (v, 1 − u): texel centres land on texel centres and charts keep their handedness,
    and the texels lie in few rows, which is what the files' writers and the post stages'
    windows are cheapest for (a long thin strip packed upright would touch every row)."""
    if turn:
        scale = np.array([atlas["width"] / h, atlas["height"] / w], dtype=np.float64)
        uv = atlas["uv"][k] * scale
        unplaced = ~uv.any(axis=(1, 2))  # triangles without area keep UVs 0, turned or not
        uv = np.stack([uv[..., 1], 1.0 - uv[..., 0]], axis=-1).astype(np.float32)
        uv[unplaced] = 0.0
    else:
        scale = np.array([atlas["width"] / w, atlas["height"] / h], dtype=np.float64)
        uv = (atlas["uv"][k] * scale).astype(np.float32)  # (T, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    areas = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * w * h  # texels²
    live = areas > 0
    if live.any():
        px = uv[live].reshape(-1, 2) * [w, h]
        rect = (
            int(np.floor(px[:, 0].min())),
            int(np.floor(px[:, 1].min())),
            int(np.ceil(px[:, 0].max())),
            int(np.ceil(px[:, 1].max())),
        )
    else:
        rect = (0, 0, 0, 0)
    return ObjectUV(mesh.name, uv, atlas_index, float(areas.sum()), rect, atlas["mesh_charts"][k])
