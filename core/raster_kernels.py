"""Compiled kernels of the bake points (numba): the rasteriser and the per-texel probe points. No bpy.

`core.raster` and `core.bakepoints` were numpy over (triangle, texel) pairs and texels; the same
arithmetic is written here as loops and compiled (`nogil`, so their worker threads run in
parallel; `cache`, so only the first bake after an install compiles), one pass over memory
instead of dozens of temporaries. Every kernel performs the numpy code's floating-point
operations in the same order, so the bake points are bit-identical to that code's
(tests/test_raster_compiled.py compares them with the numpy reference, scenekit/raster_reference.py):
where numpy's `einsum` summed three products as (x₀ + x₂) + x₁ (its SIMD loop) the kernels do
too, and where `matmul` went to BLAS, whose kernels fuse multiply-adds, they use `fma` (LLVM's
fused multiply-add: exactly rounded on every CPU; on a CPU without FMA instructions numpy's
BLAS rounds each product, and the points there differ from the old numpy path's in the last
bit, never from each other).

Nothing here compiles until `get()` is first called: numba is imported lazily (`deps`).
"""

from __future__ import annotations

import math
import threading
from types import SimpleNamespace

import numpy as np

from . import deps


# ---- helpers (compiled first, so the kernels call the compiled versions) -------------------
def fma(a, b, c):
    """a·b + c rounded once; `get()` rebinds it to LLVM's `llvm.fma.f64` (this Python form is
    only its meaning: it rounds twice)."""
    return a * b + c


def max0(x):
    """np.maximum(x, 0): NaN propagates."""
    return x if (x >= 0.0 or x != x) else 0.0


def min0(x):
    """np.minimum(x, 0): NaN propagates."""
    return x if (x <= 0.0 or x != x) else 0.0


def clip(x, lo, hi):
    """np.clip(x, lo, hi) = minimum(maximum(x, lo), hi), NaN propagating."""
    if x < lo:
        x = lo
    if x > hi:
        x = hi
    return x


def overlap_with_texel(ax, ay, bx, by, cx, cy, x0, y0):
    """The numpy `_overlap_with_texels` (scenekit/raster_reference.py) for one CCW triangle (a, b, c)
    and the texel at (x0, y0): (area, centroid x, centroid y), Green's theorem with the vertical
    extent clamped to the texel, Simpson's rule on each piece between the crossings of y = 0 and
    y = 1 (exact)."""
    area = 0.0
    mx = 0.0
    my = 0.0
    for k in range(3):
        if k == 0:
            px, py, qx, qy = ax, ay, bx, by
        elif k == 1:
            px, py, qx, qy = bx, by, cx, cy
        else:
            px, py, qx, qy = cx, cy, ax, ay
        px -= x0
        py -= y0
        qx -= x0
        qy -= y0
        dx = qx - px
        dy = qy - py
        slope = dy / dx if dx != 0.0 else 0.0
        lo = clip(min(px, qx), 0.0, 1.0)
        hi = clip(max(px, qx), 0.0, 1.0)
        # where the edge crosses y = 0 and y = 1 (numpy's `out` of -1 where the slope is 0)
        c0 = clip(px + ((0.0 - py) / slope if slope != 0.0 else -1.0), lo, hi)
        c1 = clip(px + ((1.0 - py) / slope if slope != 0.0 else -1.0), lo, hi)
        # the four cuts sorted (a sorting network: lo ≤ hi already)
        if c0 > c1:
            c0, c1 = c1, c0
        x_0, x_1, x_2, x_3 = lo, c0, c1, hi
        if x_1 < x_0:
            x_0, x_1 = x_1, x_0
        if x_3 < x_2:
            x_2, x_3 = x_3, x_2
        if x_2 < x_0:
            x_0, x_2 = x_2, x_0
        if x_3 < x_1:
            x_1, x_3 = x_3, x_1
        if x_2 < x_1:
            x_1, x_2 = x_2, x_1
        direction = 1.0 if dx > 0.0 else (-1.0 if dx < 0.0 else 0.0)
        for j in range(3):
            if j == 0:
                u, v = x_0, x_1
            elif j == 1:
                u, v = x_1, x_2
            else:
                u, v = x_2, x_3
            m = 0.5 * (u + v)
            gu = clip(py + (u - px) * slope, 0.0, 1.0)
            gm = clip(py + (m - px) * slope, 0.0, 1.0)
            gv = clip(py + (v - px) * slope, 0.0, 1.0)
            w = (v - u) / 6.0 * direction
            area -= w * (gu + 4.0 * gm + gv)
            mx -= w * (u * gu + 4.0 * m * gm + v * gv)
            my -= w * 0.5 * (gu * gu + 4.0 * gm * gm + gv * gv)
    if area > 1e-14:
        return area, x0 + mx / area, y0 + my / area
    return 0.0, x0 + mx, y0 + my


def barycentric(px, py, ax, ay, bx, by, cx, cy):
    """`bakepoints._barycentric_grouped` for one point and triangle (not clamped)."""
    v0x, v0y = bx - ax, by - ay
    v1x, v1y = cx - ax, cy - ay
    v2x, v2y = px - ax, py - ay
    den = v0x * v1y - v1x * v0y
    if den == 0.0:
        den = 1.0
    w1 = (v2x * v1y - v1x * v2y) / den
    w2 = (v0x * v2y - v2x * v0y) / den
    return 1.0 - w1 - w2, w1, w2


# ---- kernels ---------------------------------------------------------------------------------
def rasterise_chunk(p, m, off, lo, hi, counts, tri_ids, width):
    """The numpy `_rasterise_chunk` (scenekit/raster_reference.py): every positive-area overlap of
    the CCW triangles p (T, 3, 2) (texel space; edge normals m (T, 3, 2) and offsets off (T, 3)
    of e(c) = m·c − off ≥ 0 inside) with the texels of their boxes lo..hi (T, 2) (counts (T,)
    texels each), in triangle order and row by row within a triangle. Returns (triangle
    tri_ids[t], flat texel, area, centroid (n, 2)); a texel inside the triangle and a triangle
    inside a texel take fast paths, the rest `overlap_with_texel`."""
    total = 0
    for t in range(p.shape[0]):
        total += counts[t]
    tri_out = np.empty(total, np.int64)
    tex_out = np.empty(total, np.int64)
    area_out = np.empty(total)
    point_out = np.empty((total, 2))
    n = 0
    for t in range(p.shape[0]):
        ax, ay = p[t, 0, 0], p[t, 0, 1]
        bx, by = p[t, 1, 0], p[t, 1, 1]
        cx, cy = p[t, 2, 0], p[t, 2, 1]
        for iy in range(lo[t, 1], hi[t, 1] + 1):
            y0 = float(iy)
            for ix in range(lo[t, 0], hi[t, 0] + 1):
                x0 = float(ix)
                overlap = True
                full = True
                for k in range(3):
                    mx, my = m[t, k, 0], m[t, k, 1]
                    base = mx * x0 + my * y0 - off[t, k]
                    if not (base + max0(mx) + max0(my) > 0.0):  # a separating edge axis
                        overlap = False
                        break
                    if not (base + min0(mx) + min0(my) >= 0.0):
                        full = False
                if not overlap:
                    continue
                if full:  # the whole texel inside
                    area, px, py = 1.0, x0 + 0.5, y0 + 0.5
                else:
                    x1, y1 = x0 + 1, y0 + 1
                    if (
                        (ax >= x0 and ax <= x1 and ay >= y0 and ay <= y1)
                        and (bx >= x0 and bx <= x1 and by >= y0 and by <= y1)
                        and (cx >= x0 and cx <= x1 and cy >= y0 and cy <= y1)
                    ):  # the whole triangle inside the texel
                        area = abs(0.5 * ((bx - ax) * (cy - ay) - (by - ay) * (cx - ax)))
                        px, py = (ax + bx + cx) / 3.0, (ay + by + cy) / 3.0
                    else:
                        area, px, py = overlap_with_texel(ax, ay, bx, by, cx, cy, x0, y0)
                if area > 0.0:
                    tri_out[n] = tri_ids[t]
                    tex_out[n] = iy * width + ix
                    area_out[n] = area
                    point_out[n, 0] = px
                    point_out[n, 1] = py
                    n += 1
    return tri_out[:n].copy(), tex_out[:n].copy(), area_out[:n].copy(), point_out[:n].copy()


def choose_per_texel(texel, triangle, area, texels):
    """`raster.choose_per_texel` over flat texel ids < `texels`: per texel the pair of largest
    area (ties: lowest triangle, then first pair), in texel order, and the summed area of all
    its pairs in pair order (as np.bincount sums), clipped to 1."""
    best = np.full(texels, -1, np.int64)
    total = np.zeros(texels)
    for i in range(texel.shape[0]):
        x = texel[i]
        total[x] += area[i]
        j = best[x]
        if j < 0 or area[i] > area[j] or (area[i] == area[j] and triangle[i] < triangle[j]):
            best[x] = i
    n = 0
    for x in range(texels):
        if best[x] >= 0:
            n += 1
    chosen = np.empty(n, np.int64)
    coverage = np.empty(n)
    n = 0
    for x in range(texels):
        if best[x] >= 0:
            chosen[n] = best[x]
            coverage[n] = min(total[x], 1.0)
            n += 1
    return chosen, coverage


def texel_points(texel, triangle, width, texel_uv, positions, face_normal, offset, idx, offsets):
    """`BakePoints.texel_points`: for the texels idx (n,), the points at offsets (k, 2) texel
    units from each texel's corner, barycentric coordinates clamped to ≥ 0 and renormalised (so
    clamped into the texel's triangle), mapped onto the triangle (as matmul's BLAS did: fused
    multiply-adds in corner order) and pushed off along the face normal by `offset`: (n, k, 3)."""
    n, k = idx.shape[0], offsets.shape[0]
    out = np.empty((n, k, 3))
    for r in range(n):
        i = idx[r]
        x = texel[i]
        cx, cy = float(x % width), float(x // width)
        t = triangle[i]
        uv = texel_uv[t]
        pos = positions[t]
        lx, ly, lz = face_normal[i, 0] * offset, face_normal[i, 1] * offset, face_normal[i, 2] * offset
        for j in range(k):
            b0, b1, b2 = barycentric(
                cx + offsets[j, 0], cy + offsets[j, 1], uv[0, 0], uv[0, 1], uv[1, 0], uv[1, 1], uv[2, 0], uv[2, 1]
            )
            if b0 < 0.0:
                b0 = 0.0
            if b1 < 0.0:
                b1 = 0.0
            if b2 < 0.0:
                b2 = 0.0
            s = b0 + b1 + b2
            if s < 1e-300:
                s = 1e-300
            b0, b1, b2 = b0 / s, b1 / s, b2 / s
            out[r, j, 0] = fma(b2, pos[2, 0], fma(b1, pos[1, 0], b0 * pos[0, 0])) + lx
            out[r, j, 1] = fma(b2, pos[2, 1], fma(b1, pos[1, 1], b0 * pos[0, 1])) + ly
            out[r, j, 2] = fma(b2, pos[2, 2], fma(b1, pos[1, 2], b0 * pos[0, 2])) + lz
    return out


def fill_points(triangle, centroid, texel_uv, positions, normals, position, normal, face_normal, texel_size, bary):
    """`bakepoints._fill_points` but the albedo: for each texel (triangle (n,), overlap centroid
    (n, 2) texel space) its barycentric coordinates (clamped to the triangle), position, n_v
    (normalised; the face normal where it has no length), face normal (on n_v's side) and the
    world size of a texel, written into the given (n, ...) outputs."""
    for r in range(triangle.shape[0]):
        t = triangle[r]
        uv = texel_uv[t]
        pos = positions[t]
        b0, b1, b2 = barycentric(
            centroid[r, 0], centroid[r, 1], uv[0, 0], uv[0, 1], uv[1, 0], uv[1, 1], uv[2, 0], uv[2, 1]
        )
        b0, b1, b2 = clip(b0, 0.0, 1.0), clip(b1, 0.0, 1.0), clip(b2, 0.0, 1.0)
        s = b0 + b1 + b2
        b0, b1, b2 = b0 / s, b1 / s, b2 / s
        bary[r, 0], bary[r, 1], bary[r, 2] = b0, b1, b2
        for c in range(3):
            position[r, c] = b0 * pos[0, c] + b1 * pos[1, c] + b2 * pos[2, c]
        nx = b0 * normals[t, 0, 0] + b1 * normals[t, 1, 0] + b2 * normals[t, 2, 0]
        ny = b0 * normals[t, 0, 1] + b1 * normals[t, 1, 1] + b2 * normals[t, 2, 1]
        nz = b0 * normals[t, 0, 2] + b1 * normals[t, 1, 2] + b2 * normals[t, 2, 2]
        length = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / length, ny / length, nz / length
        ex, ey, ez = pos[1, 0] - pos[0, 0], pos[1, 1] - pos[0, 1], pos[1, 2] - pos[0, 2]
        gx, gy, gz = pos[2, 0] - pos[0, 0], pos[2, 1] - pos[0, 1], pos[2, 2] - pos[0, 2]
        fx, fy, fz = ey * gz - ez * gy, ez * gx - ex * gz, ex * gy - ey * gx
        area2 = math.sqrt(fx * fx + fy * fy + fz * fz)
        fx, fy, fz = fx / area2, fy / area2, fz / area2
        finite = math.isfinite(nx) and math.isfinite(ny) and math.isfinite(nz)
        if not finite or math.sqrt(nx * nx + ny * ny + nz * nz) < 0.5:  # degenerate n_v: the face's
            nx, ny, nz = fx, fy, fz
        if fx * nx + fz * nz + fy * ny < 0.0:  # einsum's order: (x₀ + x₂) + x₁
            fx, fy, fz = -fx, -fy, -fz
        normal[r, 0], normal[r, 1], normal[r, 2] = nx, ny, nz
        face_normal[r, 0], face_normal[r, 1], face_normal[r, 2] = fx, fy, fz
        texels = 0.5 * abs(
            (uv[1, 0] - uv[0, 0]) * (uv[2, 1] - uv[0, 1]) - (uv[2, 0] - uv[0, 0]) * (uv[1, 1] - uv[0, 1])
        )
        texel_size[r] = math.sqrt(0.5 * area2 / (texels if (texels >= 1e-12 or texels != texels) else 1e-12))


def buried_rays(position, face_normal, texel_size, offset, rows, directions):
    """`bakepoints.find_buried`'s probe rays from the texels `rows` (indices into the given
    (n, ...) arrays): origins (off the surface by `offset`), the local `directions` (k, 3) in the
    tangent frame of each face normal (`sh.tangent_frames`) and the reach 4 texels + 4 offsets,
    as (len(rows)·k, 3), (len(rows)·k, 3), (len(rows)·k,)."""
    k = directions.shape[0]
    origins = np.empty((rows.shape[0] * k, 3))
    dirs = np.empty((rows.shape[0] * k, 3))
    reach = np.empty(rows.shape[0] * k)
    for r in range(rows.shape[0]):
        i = rows[r]
        n0, n1, n2 = face_normal[i, 0], face_normal[i, 1], face_normal[i, 2]
        sign = 1.0 if n2 >= 0.0 else -1.0
        a = -1.0 / (sign + n2)
        b = n0 * n1 * a
        # frame rows (t_c, b_c, n_c) per world axis c (sh.tangent_frames' columns t, b, n)
        t0, t1, t2 = 1.0 + sign * (n0 * n0) * a, sign * b, -sign * n0
        s0, s1, s2 = b, sign + (n1 * n1) * a, -n1
        ox = position[i, 0] + face_normal[i, 0] * offset
        oy = position[i, 1] + face_normal[i, 1] * offset
        oz = position[i, 2] + face_normal[i, 2] * offset
        length = 4.0 * texel_size[i] + 4.0 * offset
        for j in range(k):
            q = r * k + j
            d0, d1, d2 = directions[j, 0], directions[j, 1], directions[j, 2]
            dirs[q, 0] = t0 * d0 + n0 * d2 + s0 * d1  # einsum's order: (x₀ + x₂) + x₁
            dirs[q, 1] = t1 * d0 + n1 * d2 + s1 * d1
            dirs[q, 2] = t2 * d0 + n2 * d2 + s2 * d1
            origins[q, 0], origins[q, 1], origins[q, 2] = ox, oy, oz
            reach[q] = length
    return origins, dirs, reach


def back_hits(dirs, prim, ng, k):
    """Per texel (len(prim) / k of them, k rays each) the rays that hit a triangle's back
    (dirs · ng > 0, summed as einsum did)."""
    n = prim.shape[0] // k
    out = np.zeros(n, np.int64)
    for r in range(n):
        for j in range(k):
            q = r * k + j
            g0, g1, g2 = float(ng[q, 0]), float(ng[q, 1]), float(ng[q, 2])
            if prim[q] >= 0 and dirs[q, 0] * g0 + dirs[q, 2] * g2 + dirs[q, 1] * g1 > 0.0:
                out[r] += 1
    return out


def cover_rays(texel, width, position, face_normal, offset, points, point_bits, normal_bits, corner):
    """`bakepoints.find_near_cover`'s probes, each distinct ray once: per texel (texel (n,) flat
    ids in ascending order) the bake point's origin (position + face normal × offset) and its k
    texel points (points (n, k, 3), `BakePoints.texel_points`), all probed along the face normal.
    A texel point equal, bit for bit (point_bits, normal_bits: the points and face normals viewed
    as int64), to one probed before, at an equal offset of the same texel or at the same texel
    corner (corner (k,): 0–3 for the corners (0,0), (1,0), (0,1), (1,1), −1 elsewhere) of a
    texel earlier in the chunk (neighbours on one triangle share their corners' points), reuses
    that ray: the same ray has the same answer. Returns the distinct rays' origins (m, 3) and face
    normals (m, 3), and which ray (n, k + 1) each texel's probes are."""
    n, k = points.shape[0], points.shape[1]
    origins = np.empty((n * (k + 1), 3))
    normals = np.empty((n * (k + 1), 3))
    ray = np.empty((n, k + 1), np.int64)
    first = np.full(4, -1, np.int64)  # the first offset at each corner
    for j in range(k):
        if corner[j] >= 0 and first[corner[j]] < 0:
            first[corner[j]] = j
    m = 0
    q = 0  # the first texel of the chunk at or after the one below (texel − width)
    for r in range(n):
        t = texel[r]
        x = t % width
        while q < r and texel[q] < t - width:
            q += 1
        for c in range(3):
            origins[m, c] = position[r, c] + face_normal[r, c] * offset
            normals[m, c] = face_normal[r, c]
        ray[r, 0] = m
        m += 1
        for j in range(k):
            found = -1
            for j2 in range(j):  # an equal offset of this texel
                if (
                    point_bits[r, j2, 0] == point_bits[r, j, 0]
                    and point_bits[r, j2, 1] == point_bits[r, j, 1]
                    and point_bits[r, j2, 2] == point_bits[r, j, 2]
                ):
                    found = ray[r, 1 + j2]
                    break
            if found < 0 and corner[j] >= 0:  # the same corner of an earlier texel
                ox, oy = corner[j] % 2, corner[j] // 2
                for c2 in range(4):
                    dx, dy = ox - c2 % 2, oy - c2 // 2
                    j2 = first[c2]
                    if j2 < 0 or not (dy < 0 or (dy == 0 and dx < 0)) or x + dx < 0 or x + dx >= width:
                        continue
                    want = t + dy * width + dx
                    lo, hi = (r - 1, r) if dy == 0 else (max(q - 1, 0), min(q + 2, r))
                    for s in range(max(lo, 0), hi):
                        if (
                            texel[s] == want
                            and point_bits[s, j2, 0] == point_bits[r, j, 0]
                            and point_bits[s, j2, 1] == point_bits[r, j, 1]
                            and point_bits[s, j2, 2] == point_bits[r, j, 2]
                            and normal_bits[s, 0] == normal_bits[r, 0]
                            and normal_bits[s, 1] == normal_bits[r, 1]
                            and normal_bits[s, 2] == normal_bits[r, 2]
                        ):
                            found = ray[s, 1 + j2]
                            break
                    if found >= 0:
                        break
            if found >= 0:
                ray[r, 1 + j] = found
            else:
                for c in range(3):
                    origins[m, c] = points[r, j, c]
                    normals[m, c] = face_normal[r, c]
                ray[r, 1 + j] = m
                m += 1
    return origins[:m].copy(), normals[:m].copy(), ray


def other_triangles(texel, triangle, area, chosen, face_normals, use_normals, min_cos, point, out, best, lo, hi):
    """`bakepoints.other_triangles` for the chosen pairs lo … hi − 1 (`chosen` (P,), indices into
    the pairs texel (N,) flat ids, triangle (N,), area (N,) texel units; sorted by texel): up to
    m other triangles overlapping each one's texel, largest overlap first (ties: lowest index),
    written into out (P, m) int32 (−1 where there are fewer; to start all −1), best (P, m) their
    areas; with `use_normals`, only triangles whose face normal (face_normals (T, 3) unit, dot
    product summed as einsum did) is within `min_cos` of the texel's own. point (texels,) int32
    is scratch shared between calls (each sets and reads only its own texels' entries). One pass
    over every pair, keeping each texel's m best by insertion (the numpy code's lexsort of every
    pair, scenekit/raster_reference.py, gives the same order); calls over disjoint ranges write
    disjoint rows, so they can run on parallel threads."""
    if hi <= lo:
        return
    m = out.shape[1]
    first, last = texel[chosen[lo]], texel[chosen[hi - 1]]
    for p in range(lo, hi):
        point[texel[chosen[p]]] = p
    for i in range(texel.shape[0]):
        x = texel[i]
        if x < first or x > last:  # another range's texel
            continue
        p = point[x]
        own = triangle[chosen[p]]
        t = triangle[i]
        if t == own:
            continue
        if use_normals:
            f, g = face_normals[t], face_normals[own]
            if not (f[0] * g[0] + f[2] * g[2] + f[1] * g[1] >= min_cos):
                continue
        a = area[i]
        for j in range(m):  # insert by (area descending, triangle ascending)
            if out[p, j] < 0 or a > best[p, j] or (a == best[p, j] and t < out[p, j]):
                for q in range(m - 1, j, -1):
                    out[p, q] = out[p, q - 1]
                    best[p, q] = best[p, q - 1]
                out[p, j] = t
                best[p, j] = a
                break


def spoke_targets(target, idx, texel, width, triangle, others, texel_uv, positions, face_normal, offset, offsets):
    """`bakepoints.settling._spoke_targets` after `BakePoints.texel_points`: for the texels idx (n,) (indices
    into the bake points' texel (P,) flat ids, triangle (P,), others (P, m) −1 for none,
    face_normal (P, 3)) that have other triangles, each point at offsets (k, 2) texel units from
    the texel's corner that lies on one of the texel's triangles (its own, then `others` in order;
    barycentric coordinates all ≥ 0 in texel_uv (T, 3, 2) texel units) is moved onto the first
    such: mapped onto positions (T, 3, 3) world space (matmul's fused multiply-adds, as
    `texel_points`) and pushed off along the face normal by `offset` (scene units). Writes
    target (n, k, 3) world space, which holds the points clamped into the texel's own triangle
    (`texel_points`), in place; the points on none of the texel's triangles stay."""
    m = others.shape[1]
    k = offsets.shape[0]
    done = np.zeros(k, np.bool_)
    for r in range(idx.shape[0]):
        i = idx[r]
        has = False
        for c in range(m):
            if others[i, c] >= 0:
                has = True
        if not has:
            continue
        cx, cy = float(texel[i] % width), float(texel[i] // width)
        lx, ly, lz = face_normal[i, 0] * offset, face_normal[i, 1] * offset, face_normal[i, 2] * offset
        done[:] = False
        for c in range(m + 1):
            tri = triangle[i] if c == 0 else others[i, c - 1]
            if tri < 0:
                continue
            uv, pos = texel_uv[tri], positions[tri]
            for j in range(k):
                if done[j]:
                    continue
                b0, b1, b2 = barycentric(
                    cx + offsets[j, 0], cy + offsets[j, 1], uv[0, 0], uv[0, 1], uv[1, 0], uv[1, 1], uv[2, 0], uv[2, 1]
                )
                if b0 >= 0.0 and b1 >= 0.0 and b2 >= 0.0:  # numpy's bary.min() ≥ 0: False for NaN
                    target[r, j, 0] = fma(b2, pos[2, 0], fma(b1, pos[1, 0], b0 * pos[0, 0])) + lx
                    target[r, j, 1] = fma(b2, pos[2, 1], fma(b1, pos[1, 1], b0 * pos[0, 1])) + ly
                    target[r, j, 2] = fma(b2, pos[2, 2], fma(b1, pos[1, 2], b0 * pos[0, 2])) + lz
                    done[j] = True


def spoke_rays(position, face_normal, texel_size, offset, start, target):
    """`bakepoints.settle`'s spokes of the bake points start … start + n − 1 (position, face_normal
    (P, 3), texel_size (P,) metres): from each one's ray origin (the anchor: position + face
    normal × `offset`, scene units) to its k targets (target (n, k, 3), `bakepoints.settling._spoke_targets`).
    Returns anchor (n, 3), origin (n·k, 3) (the anchor repeated), direction (n, k, 3) unit
    (zero-length spokes: 0), length (n, k) and reach (n, k) = max(length, texel size), with the
    numpy code's operations in its order (scenekit/raster_reference.py `settle`: the norm summed
    x² + y² first, then + z²; divisions by max(length, 1e-300))."""
    n, k = target.shape[0], target.shape[1]
    anchor = np.empty((n, 3))
    origin = np.empty((n * k, 3))
    direction = np.empty((n, k, 3))
    length = np.empty((n, k))
    reach = np.empty((n, k))
    for r in range(n):
        i = start + r
        ax = position[i, 0] + face_normal[i, 0] * offset
        ay = position[i, 1] + face_normal[i, 1] * offset
        az = position[i, 2] + face_normal[i, 2] * offset
        anchor[r, 0], anchor[r, 1], anchor[r, 2] = ax, ay, az
        size = texel_size[i]
        for j in range(k):
            dx, dy, dz = target[r, j, 0] - ax, target[r, j, 1] - ay, target[r, j, 2] - az
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            s = d if (d >= 1e-300 or d != d) else 1e-300  # np.maximum: NaN propagates
            direction[r, j, 0], direction[r, j, 1], direction[r, j, 2] = dx / s, dy / s, dz / s
            length[r, j] = d
            reach[r, j] = d if (d >= size or d != d) else size  # np.maximum
            q = r * k + j
            origin[q, 0], origin[q, 1], origin[q, 2] = ax, ay, az
    return anchor, origin, direction, length, reach


def components(n, left, right):
    """(n,) labels of the connected components of n nodes joined by the pairs (left[i], right[i]):
    each node's label is the smallest node of its component (union-find whose roots are always
    their set's smallest node, with path halving)."""
    parent = np.arange(n)
    for i in range(len(left)):
        a, b = left[i], right[i]
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b
    for i in range(n):  # parents precede their children: one pass resolves every root
        parent[i] = parent[parent[i]]
    return parent


_HELPERS = ("max0", "min0", "clip", "overlap_with_texel", "barycentric")
_KERNELS = (
    "components",
    "rasterise_chunk",
    "choose_per_texel",
    "texel_points",
    "fill_points",
    "buried_rays",
    "back_hits",
    "cover_rays",
    "other_triangles",
    "spoke_targets",
    "spoke_rays",
)
_compiled: SimpleNamespace | None = None
_lock = threading.Lock()


def _fma_intrinsic(numba):
    """LLVM's fused multiply-add of three float64 (`llvm.fma.f64`) as a numba intrinsic."""
    from llvmlite import ir
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def fused(typingctx, a, b, c):
        sig = numba.types.float64(numba.types.float64, numba.types.float64, numba.types.float64)

        def codegen(context, builder, signature, args):
            double = ir.DoubleType()
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(double, [double] * 3), "llvm.fma.f64")
            return builder.call(fn, args)

        return sig, codegen

    return fused


def get() -> SimpleNamespace:
    """The compiled kernels (numba.njit, nogil, cached on disk), by name. Raises
    DependencyMissing naming numba if it is not installed."""
    global _compiled
    with _lock:
        if _compiled is None:
            numba = deps.require("numba")
            jit = numba.njit(nogil=True, cache=True, error_model="numpy")
            module = globals()
            fused = _fma_intrinsic(numba)

            def fma_jit(a, b, c):
                return fused(a, b, c)

            module["fma"] = numba.njit(nogil=True, inline="always")(fma_jit)
            for name in _HELPERS:  # rebinding the globals: kernels then call compiled helpers
                module[name] = jit(module[name])
            _compiled = SimpleNamespace(**{name: jit(module[name]) for name in _KERNELS})
    return _compiled
