"""Compiled (numba) kernels of the bake points' rays: origins over a texel's footprint
(`data.BakePoints.sample_origins`) and the triangles near a box (`covers`). No bpy. Nothing
compiles until `get()` (`core.compiled`); the sequences are `core.sampling`'s.
"""

from __future__ import annotations

import numpy as np

from .. import compiled, sampling
from ..sampling import radical_inverse, sobol_pair, stream_key, uniform

#: The stream number of `footprint_origins`' first tries (`sampling.stream_key`), apart from the
#: tracer's direction streams (`tracer.hemisphere_kernels`).
_ORIGIN_STREAM = 96


def footprint_origins(
    corner, tri_uv, tri_pos, count, centroid, face_normal, offset, k, footprint, tries, seed, texels, first, key_seed
):
    """k ray origins per texel (n·k, 3), uniform over the part of the texel's central
    `footprint` × `footprint` square (texel units) covered by any of its first count (n,)
    triangles (tri_uv (n, m, 3, 2) in texel units, tri_pos (n, m, 3, 3) world space; the first
    is the texel's own; count 1: that triangle alone, as Cycles bakes a texel): rejection
    sampling, `tries` tries, then as many over the whole texel, then `centroid` (n, 3); a try is
    kept in the first triangle holding it and takes its position there, pushed off the surface
    by `offset` along `face_normal` (n, 3). corner (n, 2): the texel's corner in texel units. A
    texel straddling a triangle edge then averages its whole footprint, centred on the texel.

    The k first tries of a texel are a Hammersley set (j/k, radical inverse of j) shifted by
    one random offset per texel, modulo 1 (Cranley–Patterson): each try is uniform on its
    own, so the rejection sampling stays exact, but together they cover the square evenly,
    so a shadow edge across a texel is far less noisy than with independent tries. Given the
    texels' global ids texels (n,) (else no rows), the first tries are instead points first ..
    first + k − 1 of the texel's own (0,2)-sequence (keyed by (key_seed, texel id):
    `sobol_pair`), stratified across all the texel's passes (first: the
    pass's first sample, pass × k); later tries and everything else draw on `seed`."""
    state = np.uint64(seed)
    n = corner.shape[0]
    out = np.empty((n * k, 3))
    by_texel = texels.shape[0] > 0
    key = np.uint64(0)
    for t in range(n):
        state, shift_x = uniform(state)
        state, shift_y = uniform(state)
        if by_texel:
            key = stream_key(key_seed, texels[t], _ORIGIN_STREAM)
        for j in range(k):
            s = t * k + j
            found = False
            for attempt in range(2 * tries):
                width = footprint if attempt < tries else 1.0
                if attempt == 0 and by_texel:
                    ux, uy = sobol_pair(first + j, key)
                elif attempt == 0:
                    ux = (j / k + shift_x) % 1.0
                    uy = (radical_inverse(j) + shift_y) % 1.0
                else:
                    state, ux = uniform(state)
                    state, uy = uniform(state)
                qx = corner[t, 0] + 0.5 * (1.0 - width) + width * ux
                qy = corner[t, 1] + 0.5 * (1.0 - width) + width * uy
                for m in range(count[t]):
                    ax, ay = tri_uv[t, m, 0, 0], tri_uv[t, m, 0, 1]
                    v0x, v0y = tri_uv[t, m, 1, 0] - ax, tri_uv[t, m, 1, 1] - ay
                    v1x, v1y = tri_uv[t, m, 2, 0] - ax, tri_uv[t, m, 2, 1] - ay
                    den = v0x * v1y - v1x * v0y
                    if den == 0.0:
                        continue
                    px, py = qx - ax, qy - ay
                    w1 = (px * v1y - v1x * py) / den
                    w2 = (v0x * py - px * v0y) / den
                    w0 = 1.0 - w1 - w2
                    if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                        for c in range(3):
                            out[s, c] = w0 * tri_pos[t, m, 0, c] + w1 * tri_pos[t, m, 1, c] + w2 * tri_pos[t, m, 2, c]
                        found = True
                        break
                if found:
                    break
            if not found:  # the overlap's centroid, as Cycles gives up
                for c in range(3):
                    out[s, c] = centroid[t, c]
            for c in range(3):
                out[s, c] += face_normal[t, c] * offset
    return out


def near_box(tri, lo, hi):
    """(T,) bool: the triangles tri (T, 3, 3) whose bounding box overlaps the box lo..hi (3,)
    (`covers._near_box`: one pass over the triangles, where numpy made six over each column).
    A triangle with a NaN coordinate overlaps nothing."""
    out = np.empty(tri.shape[0], np.bool_)
    for t in range(tri.shape[0]):
        inside = True
        for i in range(3):
            a, b, c = tri[t, 0, i], tri[t, 1, i], tri[t, 2, i]
            if a != a or b != b or c != c or not (min(a, b, c) <= hi[i] and max(a, b, c) >= lo[i]):
                inside = False
                break
        out[t] = inside
    return out


KERNELS = compiled.KernelSet(__name__, kernels=("footprint_origins", "near_box"), uses=(sampling.KERNELS,))
get = KERNELS.get
