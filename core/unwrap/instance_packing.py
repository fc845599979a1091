"""The unwrap of instances: linked duplicates and collection instances sharing one lightmap UV
layer, packed as blocks and bundles into atlases of their own (`core.unwrap.instances`). No bpy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BakeError
from . import instances, xatlas_packing
from .data import MAX_RESOLUTION, ObjectUV, _check_scale, triangle_areas
from .worker_runs import _run_worker


# --- instances: linked duplicates sharing one lightmap UV layer (core.unwrap.instances) ---
def _representatives(meshes, groups) -> list[int]:
    """The mesh index charted for each instance group (its largest instance), after checking
    that no instance asks for an atlas of its own (its layer is its mesh's, shared)."""
    reps = []
    for g in groups:
        own = [meshes[i].name for i in g if meshes[i].resolution is not None or meshes[i].texel_density is not None]
        if own:
            raise BakeError(
                f"{', '.join(repr(n) for n in own)} share the mesh '{meshes[g[0]].instance_of}' with other objects "
                "and override the resolution or texel density: instances share their mesh's lightmap UVs, so "
                "they cannot have an atlas of their own; clear the override or make the object single user"
            )
        areas = [float(triangle_areas(meshes[i].positions, meshes[i].triangles).sum()) for i in g]
        reps.append(g[instances.representative(areas)])
    return reps


def _instance_atlases(groups, reps, settings, meshes):
    """[(groups [(member indices, representative)], resolution, density)] per instance atlas:
    one for all instanced meshes, or, when every object has its own atlas, one per mesh and
    collection (the meshes of one collection's instances share theirs)."""
    pairs = list(zip(groups, reps))
    if not pairs:
        return []
    if not settings.per_object:
        return [(pairs, settings.resolution, settings.texel_density)]
    root = list(range(len(pairs)))

    def find(a):
        while root[a] != a:
            a = root[a]
        return a

    first: dict[str, int] = {}
    for k, (members, _) in enumerate(pairs):
        for i in members:
            if meshes[i].bundle is not None:
                root[find(k)] = find(first.setdefault(meshes[i].bundle[0], k))
    parts: dict[int, list] = {}
    for k, pair in enumerate(pairs):
        parts.setdefault(find(k), []).append(pair)
    return [(part, settings.resolution, settings.texel_density) for part in parts.values()]


@dataclass
class _Units:
    """What an instance atlas places: per mesh group its plain instances (linked duplicates,
    mesh indices), then per collection its instancers (sorted) and each instancer's members
    (mesh indices, by member name), and per collection the group index of each member."""

    plain: list[list[int]]
    collections: list[dict[str, list[int]]]
    member_groups: list[list[int]]

    @property
    def counts(self) -> list[int]:
        """Copies per unit: each mesh group's block, then each collection's bundle."""
        return [len(p) for p in self.plain] + [len(c) for c in self.collections]


def _units(meshes, groups) -> _Units:
    """Sort the instance groups' meshes into plain instances and collection instances; raises
    BakeError when two instancers of one collection show different members."""
    group_of = {i: gi for gi, (members, _) in enumerate(groups) for i in members}
    plain: list[list[int]] = [[] for _ in groups]
    by_collection: dict[str, dict[str, list[int]]] = {}
    for gi, (members, _) in enumerate(groups):
        for i in members:
            b = meshes[i].bundle
            if b is None:
                plain[gi].append(i)
            else:
                by_collection.setdefault(b[0], {}).setdefault(b[1], []).append(i)
    collections, member_groups = [], []
    for name, by_instancer in by_collection.items():
        ordered = {e: sorted(idx, key=lambda i: meshes[i].bundle[2]) for e, idx in sorted(by_instancer.items())}
        shown = {tuple(meshes[i].bundle[2] for i in idx) for idx in ordered.values()}
        if len(shown) > 1:
            raise BakeError(
                f"the instances of collection '{name}' show different objects ({', '.join(sorted(ordered))}): "
                "unwrap them together again"
            )
        collections.append(ordered)
        member_groups.append([group_of[i] for i in next(iter(ordered.values()))])
    return _Units(plain, collections, member_groups)


def _add_instances(result, meshes, charts, groups, resolution, density, padding, cancel) -> None:
    """Pack the instance groups [(member indices, representative)] into one new atlas of `result`
    and fill in their ObjectUVs (`core.unwrap.instances`): a block per linked duplicate, a bundle per
    collection instance."""
    _check_scale(resolution, density)
    rep_charts = [charts[r] for _, r in groups]
    names = [meshes[r].name for _, r in groups]
    triangles = sum(len(meshes[r].triangles) for _, r in groups)
    units = _units(meshes, groups)
    counts = units.counts

    def pack_blocks(t):
        job = {
            "task": "each",
            "charts": [(c.chart, c.corner, c.uv) for c in rep_charts],
            "texels_per_metre": float(t),
            "padding": int(padding),
            "units": float(t) * xatlas_packing.PACK_UNITS_PER_TEXEL,
        }
        out = _run_worker(job, names, triangles, cancel)["blocks"]
        blocks = [
            instances.Block(b["uv"][0], b["width"], b["height"], b["mesh_charts"][0], b["utilisation"]) for b in out
        ]
        return blocks + [instances.bundle(blocks, m, padding) for m in units.member_groups]

    first = None
    if density is None:
        boxes = [xatlas_packing.chart_boxes([(c.chart, c.corner, c.uv)])[1] for c in rep_charts]
        boxes += [np.concatenate([boxes[g] for g in m]) for m in units.member_groups]
        first = instances.first_density(boxes, counts, resolution, padding)
    w, h, t, placed, corners, packs = instances.layout(
        pack_blocks, counts, resolution, density, padding, MAX_RESOLUTION, first
    )
    atlas_index = len(result.atlas_sizes)
    result.atlas_sizes.append((w, h))
    covered = sum(n * b.utilisation * b.width * b.height for n, b in zip(counts, placed))
    result.utilisation.append(float(covered / (w * h)))
    result.shared.append(False)
    result.part.append(0)
    result.instanced.append(True)
    result.charts += sum(n * b.charts for n, b in zip(counts, placed))
    result.stats["packs"] += packs
    result.stats["tries"].append([(float(t), True)])
    blocks = placed[: len(groups)]
    copies = iter(corners)
    for gi, members in enumerate(units.plain):
        for i in members:
            result.objects[i] = _instance_uv(meshes, i, groups[gi][1], blocks[gi], next(copies), atlas_index, (w, h))
    for ci, by_instancer in enumerate(units.collections):
        bundle = placed[len(groups) + ci]
        assert isinstance(bundle, instances.Bundle)
        for members in by_instancer.values():
            x0, y0 = (int(v) for v in next(copies))
            outer = instances.rectangle(bundle, (x0, y0), w, h)
            for i, (g, (x, y)) in zip(members, bundle.parts):
                ouv = _instance_uv(meshes, i, groups[g][1], blocks[g], (x0 + x, y0 + y), atlas_index, (w, h))
                ouv.inner = instances.rectangle(blocks[g], (x, y), bundle.width, bundle.height)
                ouv.outer = outer
                result.objects[i] = ouv


def _instance_uv(meshes, i, r, block, corner, atlas_index, size) -> ObjectUV:
    """The ObjectUV of instance `i` (representative `r`) for its block's copy at lower-left texel
    `corner` of atlas `atlas_index` of `size` (width, height)."""
    w, h = size
    reversed_ = instances.corner_map(meshes[i].triangles, meshes[r].triangles, meshes[i].name, meshes[r].instance_of)
    layer = block.uv[:, ::-1] if reversed_ else block.uv
    x, y = (int(v) for v in corner)
    rect = instances.rectangle(block, (x, y), w, h)
    uv = instances.atlas_uv(layer, rect)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    texels = float((0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])).sum() * w * h)
    return ObjectUV(
        meshes[i].name,
        uv,
        atlas_index,
        texels,
        (x, y, x + block.width, y + block.height),
        block.charts,
        np.ascontiguousarray(layer, dtype=np.float32),
        rect,
    )
