"""Compiled (numba) kernels of `tracer.lights`: emissive triangles sampled through their cluster
tree (`sample_emitters`, `emitter_pdf`), area lights by solid angle (`sample_area_light`), and
the one point, spot or area light chosen per shading point (`choose_lights`), and the emitters'
light tree built (`light_tree`, `node_sums`, `sibling_shares`). No bpy.

Each has a numpy specification in `tracer.lights` that the tests compare it with. Nothing
compiles until `get()` (`core.compiled`).
"""

from __future__ import annotations

import math

import numpy as np

from .. import compiled

_TWO_PI = 2.0 * math.pi
_BELOW_ONE = 1.0 - 2.0**-53  # the largest double below 1


def _unit3(x, y, z):
    """(x, y, z) / its length (NaN for a zero vector)."""
    inv = 1.0 / math.sqrt(x * x + y * y + z * z)
    return x * inv, y * inv, z * inv


def _spherical(x, i, triangles, t):
    """Seen from x[i] (of (R, 3)), triangle triangles[t] (T, 3, 3): unit directions a, b, c
    (3-tuples) to its corners, the cosine and sine of the angle at a and the solid angle
    (`lights.emitters.spherical_triangles`, one row; 0 seen edge-on, NaN from a corner)."""
    px, py, pz = x[i, 0], x[i, 1], x[i, 2]
    a = _unit3(triangles[t, 0, 0] - px, triangles[t, 0, 1] - py, triangles[t, 0, 2] - pz)
    b = _unit3(triangles[t, 1, 0] - px, triangles[t, 1, 1] - py, triangles[t, 1, 2] - pz)
    c = _unit3(triangles[t, 2, 0] - px, triangles[t, 2, 1] - py, triangles[t, 2, 2] - pz)
    ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    bc = b[0] * c[0] + b[1] * c[1] + b[2] * c[2]
    ca = c[0] * a[0] + c[1] * a[1] + c[2] * a[2]
    det = abs(
        a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) + a[2] * (b[0] * c[1] - b[1] * c[0])
    )
    y = bc - ab * ca  # ∝ the cosine of the angle at a, det ∝ its sine (same factor)
    h = math.sqrt(det * det + y * y)
    return a, b, c, y / h, det / h, 2.0 * math.atan2(det, 1.0 + ab + bc + ca)


def _spherical_direction(a, b, c, cos_a, sin_a, area, u1, u2):
    """A unit direction (3-tuple) uniform in the spherical triangle a, b, c with angle at a of
    cosine cos_a and sine sin_a and solid angle area (`_spherical`) for uniform numbers u1, u2
    (Arvo 1995, as `lights.emitters.sample_spherical_triangles`)."""
    s, q = -math.sin(u1 * area), -math.cos(u1 * area)  # sine and cosine of π + u1·area
    sin_phi = s * cos_a - q * sin_a
    cos_phi = q * cos_a + s * sin_a
    k1 = cos_phi + cos_a
    k2 = sin_phi - sin_a * (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
    cos_bp = (k2 + (k2 * cos_phi - k1 * sin_phi) * cos_a) / ((k2 * sin_phi + k1 * cos_phi) * sin_a)
    cos_bp = min(max(cos_bp, -1.0), 1.0)
    sin_bp = math.sqrt(max(1.0 - cos_bp * cos_bp, 0.0))
    ca = c[0] * a[0] + c[1] * a[1] + c[2] * a[2]
    e = _unit3(c[0] - ca * a[0], c[1] - ca * a[1], c[2] - ca * a[2])
    cp = (cos_bp * a[0] + sin_bp * e[0], cos_bp * a[1] + sin_bp * e[1], cos_bp * a[2] + sin_bp * e[2])
    cpb = cp[0] * b[0] + cp[1] * b[1] + cp[2] * b[2]
    cos_t = 1.0 - u2 * (1.0 - cpb)
    sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
    f = _unit3(cp[0] - cpb * b[0], cp[1] - cpb * b[1], cp[2] - cpb * b[2])
    return _unit3(cos_t * b[0] + sin_t * f[0], cos_t * b[1] + sin_t * f[1], cos_t * b[2] + sin_t * f[2])


def _surely_small(x, i, t, tri_area, bound, lo):
    """True when triangle t, inside the sphere bound[t] = (centre, radius), subtends from x[i]
    less than half the solid angle lo: Ω ≤ area / (d − radius)² with d the distance to the
    centre (every point of the triangle is at least d − radius away). Then `_spherical` need
    not be evaluated: the triangle is sampled by area either way (the half keeps triangles
    near lo, where `_spherical`'s rounding decides, on the exact test)."""
    dx, dy, dz = bound[t, 0] - x[i, 0], bound[t, 1] - x[i, 1], bound[t, 2] - x[i, 2]
    gap = math.sqrt(dx * dx + dy * dy + dz * dz) - bound[t, 3]
    return gap > 0.0 and tri_area[t] < 0.5 * lo * gap * gap


def _emitter_density(chance, area, solid_angle, cos, dist, lo, hi):
    """Density per steradian of a sampled emitter point: chance (of its cluster and triangle)
    over the solid angle where that lies in [lo, hi] (sampled by direction), else over the area
    times dist²/cos (sampled by area); 0 when not finite or grazing."""
    if solid_angle >= lo and solid_angle <= hi:
        density = chance / solid_angle
    elif cos > 1e-12:
        density = chance / area * dist * dist / cos
    else:
        return 0.0
    return density if math.isfinite(density) else 0.0


def sample_emitters(x, normals, u, triangles, tri_normal, tri_area, within, emitters, share, window):
    """One emitter sample per point x (R, 3) (`lights.emitters.EmissiveTriangles._sample_points`, one
    row at a time): a leaf of the light tree by `u[0]` (`_pick_leaf`, with normals (R, 3) or
    no rows), the triangle of the leaf by `u[1]` (the first of its rows of `key` above leaf +
    u), then, if its solid angle from x lies in window (lo, hi), a direction in it by u[2], u[3]
    (`_spherical_direction`), else a uniform point on it. u (4, R); emitters: (clusters (11,
    K): the tree's K nodes, rows as `_cluster_weights` takes them; key (E,), order (E,),
    first (K,), last (K,): each leaf's rows of key; each triangle's bounding sphere (T, 4):
    centre, radius; child_first, child_count (K + 1,), parent (K,): `lights.tree.light_tree`).
    Returns directions (R, 3), distances (R,), triangles (R,) int64 and densities (R,)."""
    clusters, key, order, first, last, bound, child_first, child_count, _ = emitters
    n = x.shape[0]
    horizon = normals.shape[0] > 0
    dirs = np.empty((n, 3))
    dist = np.empty(n)
    pick = np.empty(n, np.int64)
    pdf = np.empty(n)
    w = np.empty(clusters.shape[1])
    top = child_first.shape[0] - 1  # the first node with several children: its children's weights by blocks
    while child_count[top] == 1:
        top = child_first[top]
    top_a, top_end = child_first[top], child_first[top] + child_count[top]
    wk = np.empty((max(top_end - top_a, 0), _BLOCK))
    d2k = np.empty((max(top_end - top_a, 0), _BLOCK))
    soa = np.empty((6, _BLOCK))
    for i in range(n):
        j = i % _BLOCK
        if j == 0 and top_end - top_a > 1:
            _top_weights(x, normals, horizon, clusters, top_a, top_end, i, min(i + _BLOCK, n), wk, d2k, soa)
        top_total = -1.0  # (a tree of one leaf: no weights)
        if top_end - top_a > 1:
            top_total = _top_total(x[i, 0], x[i, 1], x[i, 2], clusters, triangles, w, top_a, top_end, wk, d2k, j)
        nx, ny, nz = _normal(normals, i)
        cluster, chance = _pick_leaf(
            x[i, 0],
            x[i, 1],
            x[i, 2],
            nx,
            ny,
            nz,
            horizon,
            clusters,
            triangles,
            w,
            child_first,
            child_count,
            u[0, i],
            share,
            top,
            top_total,
        )
        lo, hi = first[cluster], last[cluster]  # the first row whose key exceeds cluster + u
        v = cluster + u[1, i]
        while lo < hi:
            mid = (lo + hi) // 2
            if key[mid] > v:
                hi = mid
            else:
                lo = mid + 1
        t = order[lo]
        pick[i] = t
        chance *= within[t]
        nx, ny, nz = tri_normal[t, 0], tri_normal[t, 1], tri_normal[t, 2]
        omega = 0.0  # below the window: sampled by area (`_surely_small`)
        if not _surely_small(x, i, t, tri_area, bound, window[0]):
            a, b, c3, cos_a, sin_a, omega = _spherical(x, i, triangles, t)
        if omega >= window[0] and omega <= window[1]:
            d = _spherical_direction(a, b, c3, cos_a, sin_a, omega, u[2, i], u[3, i])
            along = (
                (triangles[t, 0, 0] - x[i, 0]) * nx
                + (triangles[t, 0, 1] - x[i, 1]) * ny
                + (triangles[t, 0, 2] - x[i, 2]) * nz
            )
            reach = along / (d[0] * nx + d[1] * ny + d[2] * nz)
            dirs[i, 0], dirs[i, 1], dirs[i, 2] = d
            dist[i] = reach
            pdf[i] = chance / omega if math.isfinite(reach) and reach > 0.0 else 0.0  # 0: no sample
            continue
        s = math.sqrt(u[2, i])
        b0, b1, b2 = 1.0 - s, s * (1.0 - u[3, i]), s * u[3, i]
        px = b0 * triangles[t, 0, 0] + b1 * triangles[t, 1, 0] + b2 * triangles[t, 2, 0] - x[i, 0]
        py = b0 * triangles[t, 0, 1] + b1 * triangles[t, 1, 1] + b2 * triangles[t, 2, 1] - x[i, 1]
        pz = b0 * triangles[t, 0, 2] + b1 * triangles[t, 1, 2] + b2 * triangles[t, 2, 2] - x[i, 2]
        r = math.sqrt(px * px + py * py + pz * pz)
        inv = 1.0 / max(r, 1e-300)
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = px * inv, py * inv, pz * inv
        dist[i] = r
        cos = abs(px * nx + py * ny + pz * nz) * inv
        pdf[i] = _emitter_density(chance, tri_area[t], omega, cos, r, window[0], window[1])
    return dirs, dist, pick, pdf


def emitter_pdf(x, normals, d, t, prim, triangles, tri_normal, tri_area, within, cluster_of, emitters, share, window):
    """(R,): the density per steradian with which `sample_emitters` at x (R, 3) (normals (R, 3)
    or no rows) picks the point at distance t (R,) along d (R, 3) on triangle prim (R,) (0 for
    triangles that do not emit)."""
    clusters, bound, child_first, child_count, parent = emitters[0], emitters[5], emitters[6], emitters[7], emitters[8]
    horizon = normals.shape[0] > 0
    w = np.empty(clusters.shape[1])
    path = np.empty(clusters.shape[1], np.int64)
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        tri = prim[i]
        if within[tri] <= 0.0:
            out[i] = 0.0
            continue
        nx, ny, nz = _normal(normals, i)
        chance = _leaf_chance(
            x[i, 0],
            x[i, 1],
            x[i, 2],
            nx,
            ny,
            nz,
            horizon,
            clusters,
            triangles,
            w,
            child_first,
            child_count,
            parent,
            cluster_of[tri],
            path,
            share,
        )
        chance *= within[tri]
        omega = 0.0 if _surely_small(x, i, tri, tri_area, bound, window[0]) else _spherical(x, i, triangles, tri)[5]
        cos = abs(d[i, 0] * tri_normal[tri, 0] + d[i, 1] * tri_normal[tri, 1] + d[i, 2] * tri_normal[tri, 2])
        out[i] = _emitter_density(chance, tri_area[tri], omega, cos, t[i], window[0], window[1])
    return out


def _spherical_rectangle(px, py, pz, rect, u1, u2):
    """Seen from (px, py, pz), the rectangle rect (4, 3) (its corner, unit edges ax and ay and
    az = ax × ay) with edge lengths (exl, eyl) in rect[3, 0:2]: a point on it (3-tuple) whose
    direction is uniform in its solid angle for uniform numbers u1, u2, and that solid angle
    (0 from its plane). `lights.lamps.sample_spherical_rectangles`, one row: the four corner angles
    as complex numbers multiplied together, one atan2 in all."""
    dx, dy, dz = rect[0, 0] - px, rect[0, 1] - py, rect[0, 2] - pz
    ax0, ax1, ax2 = rect[1, 0], rect[1, 1], rect[1, 2]
    ay0, ay1, ay2 = rect[2, 0], rect[2, 1], rect[2, 2]
    az0, az1, az2 = ax1 * ay2 - ax2 * ay1, ax2 * ay0 - ax0 * ay2, ax0 * ay1 - ax1 * ay0
    x0 = dx * ax0 + dy * ax1 + dz * ax2
    y0 = dx * ay0 + dy * ay1 + dz * ay2
    z = dx * az0 + dy * az1 + dz * az2
    if z == 0.0:
        return (px, py, pz), 0.0
    x1, y1 = x0 + rect[3, 0], y0 + rect[3, 1]
    zz = z * z
    h = abs(z)
    # corner angle g_i = arg(c_i + i·s_i); (g0 + g1) and (g2 + g3) as products, then their sum
    c0, s0 = x1 * y0, h * math.sqrt(x1 * x1 + y0 * y0 + zz)
    c1, s1 = -x1 * y1, h * math.sqrt(x1 * x1 + y1 * y1 + zz)
    c2, s2 = x0 * y1, h * math.sqrt(x0 * x0 + y1 * y1 + zz)
    c3, s3 = -x0 * y0, h * math.sqrt(x0 * x0 + y0 * y0 + zz)
    ca, sa = c0 * c1 - s0 * s1, c0 * s1 + s0 * c1
    cb, sb = c2 * c3 - s2 * s3, c2 * s3 + s2 * c3
    solid_angle = math.atan2(ca * sb + sa * cb, ca * cb - sa * sb)  # Σg − 2π, modulo 2π
    if solid_angle < 0.0:
        solid_angle += _TWO_PI
    inv = 1.0 / math.sqrt(cb * cb + sb * sb)  # cos, sin of g2 + g3
    v = u1 * solid_angle
    cos_v, sin_v = math.cos(v), math.sin(v)
    cos_au = (cos_v * cb + sin_v * sb) * inv  # au = u1·solid angle − (g2 + g3)
    sin_au = (sin_v * cb - cos_v * sb) * inv
    b0, b1 = -y0 / math.sqrt(zz + y0 * y0), y1 / math.sqrt(zz + y1 * y1)
    fu = (cos_au * b0 - b1) / sin_au
    cu = math.copysign(1.0 / math.sqrt(fu * fu + b0 * b0), fu)
    cu = min(max(cu, -1.0 + 1e-12), 1.0 - 1e-12)
    xu = min(max(h * cu / math.sqrt(1.0 - cu * cu), x0), x1)
    dd2 = xu * xu + zz
    dd = math.sqrt(dd2)
    h0, h1 = y0 / math.sqrt(dd2 + y0 * y0), y1 / math.sqrt(dd2 + y1 * y1)
    hv = h0 + u2 * (h1 - h0)
    yv = hv * dd / math.sqrt(max(1.0 - hv * hv, 1e-300)) if hv * hv < 1.0 - 1e-12 else y1
    point = (
        px + xu * ax0 + yv * ay0 + z * az0,
        py + xu * ax1 + yv * ay1 + z * az1,
        pz + xu * ax2 + yv * ay2 + z * az2,
    )
    return point, solid_angle


def sample_area_light(x, u1, u2, rect, light, disk, lo):
    """One sample per point x (R, 3) of an area light (`lights.lamps.Area.sample`, one row at a time):
    a point uniform in the solid angle of its rectangle rect (`_spherical_rectangle`) by u1, u2
    (R,) where that solid angle is at least lo (a disk or ellipse counted where the point lies
    in it), else a uniform point on its surface. light (4, 3): its centre, half-extent vectors
    axis_u and axis_v, unit normal (the side it emits to); disk: a disk or ellipse. Returns unit
    directions (R, 3), the solid angle each sample stands for (R,) (0 behind the light or off a
    disk) and the distances (R,) to the points."""
    n = x.shape[0]
    dirs = np.empty((n, 3))
    weight = np.empty(n)
    dist = np.empty(n)
    uu = light[1, 0] ** 2 + light[1, 1] ** 2 + light[1, 2] ** 2
    vv = light[2, 0] ** 2 + light[2, 1] ** 2 + light[2, 2] ** 2
    area = 4.0 * math.sqrt(uu * vv) * (0.25 * math.pi if disk else 1.0)
    for i in range(n):
        px, py, pz = x[i, 0], x[i, 1], x[i, 2]
        p, solid_angle = _spherical_rectangle(px, py, pz, rect, u1[i], u2[i])
        by_direction = solid_angle >= lo and math.isfinite(p[0] + p[1] + p[2])
        if not by_direction:
            if disk:
                r, phi = math.sqrt(u1[i]), _TWO_PI * u2[i]
                a, b = r * math.cos(phi), r * math.sin(phi)
            else:
                a, b = 2.0 * u1[i] - 1.0, 2.0 * u2[i] - 1.0
            p = (
                light[0, 0] + a * light[1, 0] + b * light[2, 0],
                light[0, 1] + a * light[1, 1] + b * light[2, 1],
                light[0, 2] + a * light[1, 2] + b * light[2, 2],
            )
        tx, ty, tz = p[0] - px, p[1] - py, p[2] - pz
        d = max(math.sqrt(tx * tx + ty * ty + tz * tz), 1e-30)
        wx, wy, wz = tx / d, ty / d, tz / d
        cos_l = max(-(wx * light[3, 0] + wy * light[3, 1] + wz * light[3, 2]), 0.0)
        if by_direction:
            w = solid_angle if cos_l > 0.0 else 0.0
            if disk:
                rx, ry, rz = p[0] - light[0, 0], p[1] - light[0, 1], p[2] - light[0, 2]
                a = (rx * light[1, 0] + ry * light[1, 1] + rz * light[1, 2]) / uu
                b = (rx * light[2, 0] + ry * light[2, 1] + rz * light[2, 2]) / vv
                if a * a + b * b > 1.0:
                    w = 0.0
        else:
            w = area * cos_l / (d * d)
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = wx, wy, wz
        weight[i], dist[i] = w, d
    return dirs, weight, dist


def _solid_angle(px, py, pz, triangles, t):
    """The solid angle triangles[t] subtends from (px, py, pz): 2·atan2(|a·(b×c)|, 1 + a·b + b·c
    + c·a) over unit directions to its corners (`_spherical`'s; 0 edge-on, NaN from a corner)."""
    a = _unit3(triangles[t, 0, 0] - px, triangles[t, 0, 1] - py, triangles[t, 0, 2] - pz)
    b = _unit3(triangles[t, 1, 0] - px, triangles[t, 1, 1] - py, triangles[t, 1, 2] - pz)
    c = _unit3(triangles[t, 2, 0] - px, triangles[t, 2, 1] - py, triangles[t, 2, 2] - pz)
    det = abs(
        a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) + a[2] * (b[0] * c[1] - b[1] * c[0])
    )
    ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    bc = b[0] * c[0] + b[1] * c[1] + b[2] * c[2]
    ca = c[0] * a[0] + c[1] * a[1] + c[2] * a[2]
    return 2.0 * math.atan2(det, 1.0 + ab + bc + ca)


def _cluster_weights(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, first, end):
    """Into w[first:end] (of (K,)): each emitter cluster's (light tree node's, columns first ..
    end − 1) power over max(distance², radius²) from the point
    (px, py, pz), times (if `horizon`) the largest cosine to the unit normal (nx, ny, nz) of a
    direction into the cluster's bounding sphere (0 for a cluster wholly below the horizon);
    returns their sum, in index order. A cluster of one triangle that x lies near (distance² below
    its row 8) weighs its emitted luminance (row 7) times the solid angle the triangle subtends
    from x instead of power over distance²: beside a lamp's quad, the triangle the point sits by
    subtends far more than its twin, which power over distance² cannot tell apart (the horizon
    factor is kept). clusters (11, K): rows centre x, y, z, radius², radius, power, the lone
    triangle's id in triangles (T, 3, 3) (−1: several), its luminance, the near distance², the
    distance² from which the tree below is descended by power alone (`_pick_leaf`), its share of
    its siblings' summed power (`lights.emitters.sibling_shares`).
    One pass, each cluster's weight finished before the next (its horizon factor's square roots
    only where the normal points outside the cone into the sphere, its solid angle only where x
    lies near): a few clusters per call, so a branch is cheaper than the vectorised loops this
    replaced (bit for bit their values; no fast-math, which would reassociate the sum and make
    its last bits depend on the arrays' alignment: a seed would no longer reproduce a bake bit
    for bit across processes). Scalars and three arrays: a call's cost grows with its arguments.
    With d the distance, r the radius and a = normal · (centre − x): the normal lies inside
    the cone of directions into the sphere when a ≥ √(d² − r²), else the nearest edge's
    cosine is (a √(d² − r²) + √(d² − a²) r) / d²; inside the sphere, 1."""
    total = 0.0
    for c in range(first, end):
        dx, dy, dz = clusters[0, c] - px, clusters[1, c] - py, clusters[2, c] - pz
        d2 = dx * dx + dy * dy + dz * dz
        r2 = clusters[3, c]
        if horizon:
            a = nx * dx + ny * dy + nz * dz
            h2 = d2 - r2
            d2s = _max(d2, 1e-300)
            if h2 > 0.0 and (a < 0.0 or a * a < h2):  # the normal outside the cone: its edge's cosine
                edge = a * math.sqrt(h2) + math.sqrt(_max(d2 - a * a, 0.0)) * clusters[4, c]  # × d2
                wc = clusters[5, c] * _max(edge, 0.0) / (_max(d2, r2) * d2s)
            else:
                wc = clusters[5, c] * d2s / (_max(d2, r2) * d2s)
        else:
            wc = clusters[5, c] / _max(d2, r2)
        if d2 < clusters[8, c] and clusters[6, c] >= 0.0 and wc > 0.0:  # a lone triangle near x
            omega = _solid_angle(px, py, pz, triangles, int(clusters[6, c]))
            if math.isfinite(omega):  # NaN from a corner: keep the distance's weight
                wc *= clusters[7, c] * omega * max(d2, r2) / clusters[5, c]
        w[c] = wc
        total += wc
    return total


#: Points whose weights of the tree's top nodes `sample_emitters` computes together (`_top_weights`).
_BLOCK = 128


def _top_weights(x, normals, horizon, clusters, a, end, i0, i1, wk, d2k, soa):
    """`_cluster_weights`' distance and horizon weights of the nodes a .. end − 1 at the points
    x[i0:i1] into wk[k, j] (node a + k, point i0 + j), their distances² into d2k: node by node
    over the points (copied into the rows of soa (6, block) first: contiguous), branch-free, so
    the inner loop vectorises (the same operations, so the same bits). The near solid angles
    follow per point (`_top_total`)."""
    m = i1 - i0
    for j in range(m):
        soa[0, j], soa[1, j], soa[2, j] = x[i0 + j, 0], x[i0 + j, 1], x[i0 + j, 2]
    if horizon:
        for j in range(m):
            soa[3, j], soa[4, j], soa[5, j] = normals[i0 + j, 0], normals[i0 + j, 1], normals[i0 + j, 2]
    px, py, pz, nx, ny, nz = soa[0], soa[1], soa[2], soa[3], soa[4], soa[5]
    for k in range(end - a):
        c = a + k
        cx, cy, cz, r2, r, power = (
            clusters[0, c],
            clusters[1, c],
            clusters[2, c],
            clusters[3, c],
            clusters[4, c],
            clusters[5, c],
        )
        wrow, drow = wk[k], d2k[k]
        if horizon:
            for j in range(m):
                dx, dy, dz = cx - px[j], cy - py[j], cz - pz[j]
                d2 = dx * dx + dy * dy + dz * dz
                along = nx[j] * dx + ny[j] * dy + nz[j] * dz
                h2 = d2 - r2
                edge = along * math.sqrt(_max(h2, 0.0)) + math.sqrt(_max(d2 - along * along, 0.0)) * r
                outside = (h2 > 0.0) & ((along < 0.0) | (along * along < h2))
                d2s = _max(d2, 1e-300)
                wrow[j] = power * (_max(edge, 0.0) if outside else d2s) / (_max(d2, r2) * d2s)
                drow[j] = d2
        else:
            for j in range(m):
                dx, dy, dz = cx - px[j], cy - py[j], cz - pz[j]
                d2 = dx * dx + dy * dy + dz * dz
                wrow[j] = power / _max(d2, r2)
                drow[j] = d2


def _top_total(px, py, pz, clusters, triangles, w, a, end, wk, d2k, j):
    """The weights of nodes a .. end − 1 at point (px, py, pz), column j of `_top_weights`, into
    w[a:end], a lone triangle near the point by its solid angle as `_cluster_weights` does;
    returns their sum, in index order."""
    total = 0.0
    for k in range(end - a):
        c = a + k
        wc, d2 = wk[k, j], d2k[k, j]
        if d2 < clusters[8, c] and clusters[6, c] >= 0.0 and wc > 0.0:
            omega = _solid_angle(px, py, pz, triangles, int(clusters[6, c]))
            if math.isfinite(omega):
                wc *= clusters[7, c] * omega * max(d2, clusters[3, c]) / clusters[5, c]
        w[c] = wc
        total += wc
    return total


def _max(a, b):
    """max(a, b) as numba's builtin gives it (b where b > a, else a: a NaN or a tie keeps a), in
    a form LLVM vectorises: a loop calling the builtin stays scalar."""
    return b if b > a else a


def _child_chance(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, first, end, share):
    """(scale, mix) of the choice among the light tree nodes first .. end − 1 (siblings) at
    (px, py, pz): node c is picked with probability scale·w[c] + mix·clusters[10, c] (its share
    of the siblings' power; `_cluster_weights` into w, `_cluster_chances`)."""
    total = _cluster_weights(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, first, end)
    return _cluster_chances(total, share)


def _pick_leaf(
    px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, child_first, child_count, u, share, top=-1, top_total=-1.0
):
    """(leaf, chance): a leaf of the light tree (`lights.tree.light_tree`: child_first, child_count
    (N + 1,), the last entry the root) picked at (px, py, pz) by the uniform number u, one level
    at a time among a node's children (`_child_chance`), u rescaled to the picked child's
    interval for the next level; below a node the point lies far from (distance² at least its
    clusters[9]), by power alone (clusters[10]): its leaves' weights would differ little.
    chance: the product of the levels' probabilities. top_total ≥ 0: node `top`'s children's
    weights are already in w, summing to it (`_top_total`)."""
    node = child_first.shape[0] - 1
    chance = 1.0
    far = False
    while child_count[node] > 0:
        a, end = child_first[node], child_first[node] + child_count[node]
        if end - a == 1:
            node = a
            continue
        if far:
            scale, mix = 0.0, 1.0
        elif node == top and top_total >= 0.0:
            scale, mix = _cluster_chances(top_total, share)
        else:
            scale, mix = _child_chance(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, a, end, share)
        pick, below, acc = end - 1, 0.0, 0.0
        for c in range(a, end):
            below = acc
            acc += (scale * w[c] if scale > 0.0 else 0.0) + mix * clusters[10, c]
            if u < acc:
                pick = c
                break
        p = (scale * w[pick] if scale > 0.0 else 0.0) + mix * clusters[10, pick]
        chance *= p
        u = min(max((u - below) / p, 0.0), _BELOW_ONE) if p > 0.0 else 0.0
        node = pick
        far = far or (child_count[node] > 0 and _far_from(px, py, pz, clusters, node))  # (a leaf ends)
    return node, chance


def _far_from(px, py, pz, clusters, c):
    """True when (px, py, pz) lies at least clusters[9, c] (distance²) from node c's centre."""
    dx, dy, dz = clusters[0, c] - px, clusters[1, c] - py, clusters[2, c] - pz
    return dx * dx + dy * dy + dz * dz >= clusters[9, c]


def _leaf_chance(
    px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, child_first, child_count, parent, leaf, path, share
):
    """The probability with which `_pick_leaf` at (px, py, pz) picks `leaf`: its levels'
    probabilities multiplied from the root down, as `_pick_leaf` does (parent (N,): N for a
    top cluster; path: scratch of N entries)."""
    root = child_first.shape[0] - 1
    depth = 0
    c = leaf
    while c != root:
        path[depth] = c
        depth += 1
        c = parent[c]
    chance = 1.0
    node = root
    far = False
    for j in range(depth - 1, -1, -1):
        c = path[j]
        a, end = child_first[node], child_first[node] + child_count[node]
        if end - a > 1:
            if far:
                chance *= clusters[10, c]
            else:
                scale, mix = _child_chance(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, a, end, share)
                chance *= scale * w[c] + mix * clusters[10, c]
        node = c
        far = far or (j > 0 and _far_from(px, py, pz, clusters, node))  # (the leaf ends)
    return chance


def _horizon_bound(a, d2, r2, r):
    """The largest cosine to a unit normal of a direction into a sphere of radius r (r2 = r²)
    whose centre lies at distance² d2 and at a = normal · (centre − point): 1 where the normal
    points into the sphere or the point lies inside it, 0 wholly below the horizon
    (`_cluster_weights`' formula)."""
    h2 = d2 - r2
    if h2 <= 0.0 or (a >= 0.0 and a * a >= h2):
        return 1.0
    edge = a * math.sqrt(h2) + math.sqrt(max(d2 - a * a, 0.0)) * r
    return max(edge, 0.0) / max(d2, 1e-300)


def choose_lights(x, normals, u, table, share):
    """Which one light of `table` (L, 13) each point x (R, 3) samples (`lights.choice.Choice`), by its
    number u (R,): light l with probability (1 − share)·w_l / Σw + share·I_l / ΣI over the
    lights with w_l > 0, w_l = I_l × b_l × h_l / max(d², r²): I its largest radiant intensity,
    b its bound on the cosine at the light (one-sided lights, m ≠ 0: 0 where the point lies
    behind or in its plane, else ≤ min(1, s / (d − r)) with s the point's height above it), h
    the horizon bound at the point (`_horizon_bound`; 1 without normals (no rows)), and 0
    outside a spot's cone widened by the angle its sphere subtends. Rows of table: centre x, y,
    z, r², r, I, the unit normal m (zeros: lights all round), a spot's unit axis and cone
    half-angle (π: not a spot).
    Returns the lights (R,) int64 (−1 where no light can reach the point: none sampled) and
    their probabilities (R,)."""
    n = x.shape[0]
    m = table.shape[0]
    horizon = normals.shape[0] > 0
    choice = np.empty(n, np.int64)
    prob = np.zeros(n)
    w = np.empty(m)
    for i in range(n):
        nx, ny, nz = _normal(normals, i)
        total = 0.0
        power = 0.0
        able = 0
        for k in range(m):
            dx, dy, dz = table[k, 0] - x[i, 0], table[k, 1] - x[i, 1], table[k, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            bound = table[k, 5] / max(d2, table[k, 3])
            if horizon:
                bound *= _horizon_bound(nx * dx + ny * dy + nz * dz, d2, table[k, 3], table[k, 4])
            s = -(dx * table[k, 6] + dy * table[k, 7] + dz * table[k, 8])
            if table[k, 6] != 0.0 or table[k, 7] != 0.0 or table[k, 8] != 0.0:
                gap = math.sqrt(d2) - table[k, 4]
                bound = 0.0 if s <= 0.0 else (bound * min(1.0, s / gap) if gap > 0.0 else bound)
            if table[k, 12] < math.pi and d2 > table[k, 3]:  # a spot: outside its cone, dark
                d = math.sqrt(d2)
                along = -(dx * table[k, 9] + dy * table[k, 10] + dz * table[k, 11]) / d
                if math.acos(min(max(along, -1.0), 1.0)) > table[k, 12] + math.asin(table[k, 4] / d):
                    bound = 0.0
            w[k] = bound if bound > 0.0 and math.isfinite(bound) else 0.0
            total += w[k]
            if w[k] > 0.0:
                power += table[k, 5]
                able += 1
        choice[i] = -1
        if total <= 0.0:
            continue
        acc = 0.0
        for k in range(m):
            if w[k] <= 0.0:
                continue
            # (one light that can: probability 1 exactly, as without a choice)
            p = (1.0 - share) * w[k] / total + share * table[k, 5] / power if able > 1 else 1.0
            acc += p
            choice[i], prob[i] = k, p
            if u[i] < acc:
                break
    return choice, prob


def _normal(normals, i):
    """normals[i] as a 3-tuple, or zeros when normals has no rows."""
    if normals.shape[0] == 0:
        return 0.0, 0.0, 0.0
    return normals[i, 0], normals[i, 1], normals[i, 2]


def _cluster_chances(total, share):
    """(scale, mix): cluster c's probability is scale·w_c + mix·power_c / Σpower, i.e.
    (1 − share)·w_c / Σw + share·power_c / Σpower, or power alone where every w is 0 (all
    below the horizon); total = Σw. Scalars: an array returned per row would cost atomic
    reference counts."""
    if total <= 0.0:
        return 0.0, 1.0
    return (1.0 - share) / total, share


def _cluster_splits(centroids, perm, start, end, most, first, last, base, extent):
    """`lights.tree.cluster_splits` of the points centroids[perm[start:end]] (E, 3), in place:
    perm[start:end] reordered so that each of the k ≤ `most` clusters is a run, cluster j's being
    perm[first[base + j]:last[base + j]]; `extent` (≥ most,) scratch. Returns k. The same
    clusters, numbered alike: the same comparisons on the same float64 values (a box's diagonal
    as numpy's `norm` of its `ptp`, the first of equal maxima)."""
    first[base], last[base] = start, end
    extent[0] = _diagonal(centroids, perm, start, end)
    k = 1
    while k < most:
        c = 0
        for j in range(1, k):
            if extent[j] > extent[c]:
                c = j
        if extent[c] <= 0.0:
            break
        s, e = first[base + c], last[base + c]
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for i in range(s, e):
            for a in range(3):
                v = centroids[perm[i], a]
                lo[a] = min(lo[a], v)
                hi[a] = max(hi[a], v)
        axis = 0
        for a in (1, 2):
            if hi[a] - lo[a] > hi[axis] - lo[axis]:
                axis = a
        mid = 0.5 * (lo[axis] + hi[axis])
        upper = 0
        for i in range(s, e):
            upper += centroids[perm[i], axis] >= mid
        strict = upper == e - s  # the middle rounds onto the lowest point: split off the lowest points
        m = s  # lower points to the front, upper to the back
        for i in range(s, e):
            v = centroids[perm[i], axis]
            if not (v > lo[axis] if strict else v >= mid):
                perm[m], perm[i] = perm[i], perm[m]
                m += 1
        last[base + c], first[base + k], last[base + k] = m, m, e
        extent[c] = _diagonal(centroids, perm, s, m)
        extent[k] = _diagonal(centroids, perm, m, e)
        k += 1
    return k


def _diagonal(centroids, perm, start, end):
    """The length of the diagonal of the box of centroids[perm[start:end]] (as numpy's
    `norm(ptp(points, axis=0))`, the squares summed in axis order)."""
    total = 0.0
    for a in range(3):
        lo, hi = np.inf, -np.inf
        for i in range(start, end):
            v = centroids[perm[i], a]
            lo = min(lo, v)
            hi = max(hi, v)
        total += (hi - lo) * (hi - lo)
    return math.sqrt(total)


def light_tree(centroids, top, fanout, most_leaves):
    """`lights.tree.light_tree` compiled (the same tree: the numpy function is its
    specification, the tests compare them): the points centroids (E ≥ 1, 3) split into at most
    `top` top clusters, then breadth first each cluster of several points into at most `fanout`,
    until every leaf is one point (or coincident points) or there are `most_leaves` leaves.
    Returns (leaf (E,), child_first (N + 1,), child_count (N + 1,), parent (N,)), as it does."""
    n = len(centroids)
    cap = top + 2 * max(most_leaves, 1) + fanout + 1
    perm = np.arange(n)
    first = np.zeros(cap, np.int64)
    last = np.zeros(cap, np.int64)
    child_first = np.zeros(cap + 1, np.int64)
    child_count = np.zeros(cap + 1, np.int64)
    parent = np.full(cap, -1, np.int64)
    extent = np.empty(max(top, fanout, 1) + 1)
    k = _cluster_splits(centroids, perm, 0, n, top, first, last, 0, extent)
    nodes, leaves, c = k, k, 0
    while c < nodes and leaves < most_leaves:
        s, e = first[c], last[c]
        m = 1
        if e - s > 1:
            m = _cluster_splits(
                centroids, perm, s, e, min(fanout, most_leaves - leaves + 1), first, last, nodes, extent
            )
        if m > 1:
            child_first[c], child_count[c] = nodes, m
            parent[nodes : nodes + m] = c
            nodes += m
            leaves += m - 1
        c += 1
    leaf = np.zeros(n, np.int64)
    for c in range(nodes):
        if child_count[c] == 0:
            for i in range(first[c], last[c]):
                leaf[perm[i]] = c
    child_first[nodes], child_count[nodes] = 0, k
    parent_of = parent[:nodes].copy()
    for c in range(nodes):
        if parent_of[c] < 0:
            parent_of[c] = nodes
    return leaf, child_first[: nodes + 1].copy(), child_count[: nodes + 1].copy(), parent_of


def node_sums(lo, hi, power, child_first, child_count):
    """`lights.tree.node_sums` compiled (the same bits: its children's power summed in numpy's
    order, `_pairwise_sum`), in place."""
    for node in range(len(power) - 1, -1, -1):
        a, m = child_first[node], child_count[node]
        if m:
            for axis in range(3):
                low, high = lo[a, axis], hi[a, axis]
                for c in range(a + 1, a + m):
                    low = min(low, lo[c, axis])
                    high = max(high, hi[c, axis])
                lo[node, axis], hi[node, axis] = low, high
            power[node] = _pairwise_sum(power, a, a + m)


def _pairwise_sum(values, start, end):
    """values[start:end].sum() as numpy adds a contiguous float64 run (its pairwise summation:
    eight partial sums over blocks of up to 128, halves above), to the bit."""
    n = end - start
    if n < 8:
        total = 0.0
        for i in range(start, end):
            total += values[i]
        return total
    if n > 128:
        half = n // 2
        half -= half % 8
        return _pairwise_sum(values, start, start + half) + _pairwise_sum(values, start + half, end)
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = start + 8
    while i < end - n % 8:
        r0, r1, r2, r3 = r0 + values[i], r1 + values[i + 1], r2 + values[i + 2], r3 + values[i + 3]
        r4, r5, r6, r7 = r4 + values[i + 4], r5 + values[i + 5], r6 + values[i + 6], r7 + values[i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < end:
        total += values[i]
        i += 1
    return total


def sibling_shares(power, child_first, child_count):
    """`lights.emitters.sibling_shares` compiled (the same loop: the same bits)."""
    share = np.ones(len(power))
    for node in range(len(child_count)):
        a, m = child_first[node], child_count[node]
        total = 0.0
        for c in range(a, a + m):
            total += power[c]
        for c in range(a, a + m):
            share[c] = power[c] / total
    return share


_HELPERS = (
    "_solid_angle",
    "_cluster_weights",
    "_top_weights",
    "_top_total",
    "_max",
    "_normal",
    "_cluster_chances",
    "_far_from",
    "_child_chance",
    "_pick_leaf",
    "_leaf_chance",
    "_horizon_bound",
    "_unit3",
    "_spherical",
    "_spherical_direction",
    "_emitter_density",
    "_surely_small",
    "_spherical_rectangle",
)
#: every per-sample helper inlined: they run per sample, and a call costs more than most of them
KERNELS = compiled.KernelSet(
    __name__,
    kernels=(
        "sample_emitters",
        "sample_area_light",
        "choose_lights",
        "emitter_pdf",
        "light_tree",
        "node_sums",
        "sibling_shares",
    ),
    # the light tree's, built once per bake: not inlined
    helpers=(*_HELPERS, "_cluster_splits", "_diagonal", "_pairwise_sum"),
    allocating=("_cluster_splits",),
    inline=_HELPERS,
)
get = KERNELS.get
