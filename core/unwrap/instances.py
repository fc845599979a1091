"""Lightmap UVs for instances: objects sharing one mesh (linked duplicates, collection
instances). No bpy.

All instances of a mesh share the mesh's one lightmap UV layer, so they share one chart layout.
The mesh is charted once (on its instance with the largest surface, in metres: every other
instance then gets at least the density it would get alone) and its charts are packed alone by
xatlas into a *block* of w × h texels; the layer holds the block's UVs in [0, 1]². Each instance
gets its own copy of the block in the atlas, placed by a shelf packer (`shelf_pack`) on whole
texels with `padding` texels between blocks, so

    atlas_uv = layer_uv · scale + offset,   scale = (w / W, h / H),   offset = (x / W, y / H)

for an atlas of W × H texels and the block's lower-left texel (x, y): a texel of the block is a
texel of the atlas, the padding xatlas keeps inside the block is kept exactly, and every instance
of a mesh has the same scale. (scale, offset) is the instance's *rectangle* (docs/format.md,
"Instances").

Collection instances (an Empty showing a collection) place the collection's members together:
each member's block is packed once into the collection's *bundle* (`bundle`, a shelf pack), and
each instancer gets a copy of the bundle, so a member's rectangle is the composition of its
*inner* rectangle in the bundle (the same for every instancer) and the instancer's *outer*
rectangle in the atlas: atlas_uv = (layer_uv · inner.scale + inner.offset) · outer.scale +
outer.offset, on whole texels, equal to its rectangle. A preview reads the outer one from the
instancer and the inner one from the member.

The instances of the meshes go into an atlas of their own (one per mesh, or per collection,
when every object has its own atlas): at a fixed resolution R its density is searched so that
the blocks fill R² (`layout`), at a fixed texel density its size is what the blocks need.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import BakeError

#: Density search for a fixed resolution: rounds, the share of the atlas area the blocks' first
#: estimate aims at, the margin taken when shrinking, and when a fitting pack is grown once more.
FIT_ROUNDS, FIRST_FILL, SHRINK, GROW_BELOW = 8, 0.7, 0.97, 0.85


@dataclass
class Block:
    """One mesh's charts packed alone: uv (T, 3, 2) float32 per corner of the representative's
    triangles in [0, 1]² of the block; width × height texels; charts; utilisation of the block."""

    uv: np.ndarray
    width: int
    height: int
    charts: int
    utilisation: float


@dataclass
class Bundle:
    """A collection's member blocks packed together: the block every instance of the collection
    (an Empty instancing it) gets a copy of. width × height texels; parts: per member, in the
    members' order, (index of its mesh's Block, lower-left texel (x, y) in the bundle)."""

    width: int
    height: int
    charts: int
    utilisation: float
    parts: list[tuple[int, tuple[int, int]]]


def bundle(blocks: list[Block], members: list[int], gap: int) -> Bundle:
    """Shelf-pack the blocks `members` (indices into `blocks`, one per member object, a mesh's
    block once per member using it) `gap` texels apart into one Bundle, about square."""
    sizes = np.array([(blocks[g].width, blocks[g].height) for g in members], dtype=np.int64)
    corners, w, h = shelf_pack(sizes, square_width(sizes, gap), gap)
    covered = sum(blocks[g].utilisation * blocks[g].width * blocks[g].height for g in members)
    parts = [(g, (int(c[0]), int(c[1]))) for g, c in zip(members, corners)]
    return Bundle(w, h, sum(blocks[g].charts for g in members), float(covered / (w * h)), parts)


def instance_groups(keys: list[str | None], always: set[str] | frozenset[str] = frozenset()) -> list[list[int]]:
    """Indices of the meshes sharing a key (the mesh a linked duplicate uses), for keys held by
    two or more meshes or named in `always` (a mesh a collection instance shows: instanced even
    once), in the order of their first member; None never groups."""
    members: dict[str, list[int]] = {}
    for i, key in enumerate(keys):
        if key is not None:
            members.setdefault(key, []).append(i)
    return [m for k, m in members.items() if len(m) > 1 or k in always]


def representative(areas: list[float]) -> int:
    """Position of the instance to chart: the largest surface (ties: the first)."""
    return int(np.argmax(np.asarray(areas, dtype=np.float64)))


def corner_map(triangles: np.ndarray, reference: np.ndarray, name: str, mesh: str) -> bool:
    """Whether an instance's triangles (T, 3) are the representative's with every triangle's
    corners reversed (a mirrored instance, see `bridge.mesh_data.mirrors`) rather than the same.
    Raises BakeError if they are neither (the objects do not share one mesh)."""
    t, r = np.asarray(triangles), np.asarray(reference)
    if t.shape == r.shape and np.array_equal(t, r):
        return False
    if t.shape == r.shape and np.array_equal(t, r[:, ::-1]):
        return True
    raise BakeError(f"'{name}' is listed as an instance of '{mesh}' but its triangles differ: unwrap it again")


def shelf_pack(sizes: np.ndarray, width: int, gap: int) -> tuple[np.ndarray, int, int]:
    """Place rectangles of `sizes` (N, 2) whole texels (w, h) in rows ("shelves") of at most
    `width` texels, tallest first, `gap` texels apart (none at the atlas border: xatlas keeps
    none there either). Returns (lower-left corners (N, 2) int64, used width, used height)."""
    sizes = np.asarray(sizes, dtype=np.int64)
    order = np.lexsort((-sizes[:, 0], -sizes[:, 1]))
    pos = np.zeros((len(sizes), 2), dtype=np.int64)
    x = y = shelf = used_w = 0
    for i in order:
        w, h = (int(v) for v in sizes[i])
        if x > 0 and x + w > width:
            x, y, shelf = 0, y + shelf + gap, 0
        pos[i] = (x, y)
        used_w = max(used_w, x + w)
        x += w + gap
        shelf = max(shelf, h)
    return pos, used_w, (y + shelf if len(sizes) else 0)


def square_width(sizes: np.ndarray, gap: int) -> int:
    """A shelf width for a fixed density: about the square root of the blocks' padded area (and
    never less than the widest block), so the atlas comes out about square."""
    s = np.asarray(sizes, dtype=np.float64) + gap
    return int(max(np.asarray(sizes)[:, 0].max(), np.ceil(1.05 * np.sqrt((s[:, 0] * s[:, 1]).sum()))))


def first_density(boxes: list[np.ndarray], counts: list[int], resolution: int, padding: int) -> float:
    """Texels per metre at which the charts' padded bounding boxes (per mesh (C, 2) metres),
    each mesh counted once per instance, cover FIRST_FILL of a resolution² atlas."""
    q = 2.0 * padding + 2.0
    a = sum(n * float((b[:, 0] * b[:, 1]).sum()) for b, n in zip(boxes, counts))
    lin = sum(n * q * float(b.sum()) for b, n in zip(boxes, counts))
    c = sum(n * len(b) for b, n in zip(boxes, counts)) * q * q - FIRST_FILL * resolution * resolution
    if c >= 0 or a <= 0:
        raise BakeError(
            f"the instanced meshes' {sum(len(b) for b in boxes)} charts, once per instance, need more than a "
            f"{resolution}² atlas for their padding alone: raise the resolution or lower the padding"
        )
    return float((-lin + np.sqrt(lin * lin - 4.0 * a * c)) / (2.0 * a))


def layout(
    pack_blocks: Callable[[float], list[Block | Bundle]],
    counts: list[int],
    resolution: int | None,
    density: float | None,
    padding: int,
    max_resolution: int,
    first: float | None = None,
) -> tuple[int, int, float, list[Block | Bundle], np.ndarray, int]:
    """Pack the blocks, `counts[g]` copies of mesh group g's: at `density` texels per metre into
    an atlas as large as they need (≤ max_resolution), else at the largest density found within
    FIT_ROUNDS rounds that fits resolution² (starting at `first`). pack_blocks(t) packs every
    group's charts alone at t. Returns (width, height, density, blocks, corners (N, 2) of the
    copies in group order, packs). Raises BakeError when nothing fits."""

    def place(blocks, width):
        sizes = np.repeat([(b.width, b.height) for b in blocks], counts, axis=0)
        return shelf_pack(sizes, width, padding)

    if density is not None:
        blocks = pack_blocks(density)
        sizes = np.array([(b.width, b.height) for b in blocks])
        corners, w, h = place(blocks, square_width(np.repeat(sizes, counts, axis=0), padding))
        if max(w, h) > max_resolution:
            raise BakeError(
                f"texel density {density:g}/m needs a {w}×{h} atlas for the instances, larger than "
                f"{max_resolution}²: lower the density"
            )
        return w, h, density, blocks, corners, 1
    assert resolution is not None and first is not None
    t, best, packs = first, None, 0
    for _ in range(FIT_ROUNDS):
        blocks = pack_blocks(t)
        packs += 1
        if max(b.width for b in blocks) > resolution:
            t *= SHRINK * resolution / max(b.width for b in blocks)
            continue
        corners, w, h = place(blocks, resolution)
        if h <= resolution:
            if best is None or t > best[2]:
                best = (resolution, resolution, t, blocks, corners)
            if h >= GROW_BELOW * resolution:
                break
            t *= min(1.3, np.sqrt(resolution / h)) * 0.99
        else:
            if best is not None:
                break
            t *= SHRINK * np.sqrt(resolution / h)
    if best is None:
        raise BakeError(
            f"could not fit the instances' blocks into one {resolution}² atlas: raise the resolution "
            "or lower the padding"
        )
    return (*best, packs)


def rectangle(block: Block | Bundle, corner, width: int, height: int) -> tuple[float, float, float, float]:
    """(scale u, scale v, offset u, offset v) of a block copy at lower-left texel `corner` in a
    width × height atlas (or bundle): atlas_uv = layer_uv · scale + offset."""
    return (block.width / width, block.height / height, corner[0] / width, corner[1] / height)


def atlas_uv(layer_uv: np.ndarray, rect) -> np.ndarray:
    """Atlas UVs (..., 2) float32 of layer UVs (..., 2) through rect (su, sv, ou, ov), in float64."""
    r = np.asarray(rect, dtype=np.float64)
    return (np.asarray(layer_uv, dtype=np.float64) * r[:2] + r[2:]).astype(np.float32)
