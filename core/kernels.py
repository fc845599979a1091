"""Compiled per-sample kernels of the tracer (numba). No bpy.

The tracer is a wavefront over numpy batches with Embree queries in between; what happens per
sample between two queries (making camera rays over a texel, turning a hit into the next
bounce, projecting radiance to SH) is written here as loops over samples and compiled, one
pass over memory instead of a dozen numpy temporaries (in numpy this work outweighed Embree's
own; ARCHITECTURE.md). Compiled with `nogil`, so the tracer's threads run them in parallel,
and `cache`, so only the first bake after an install compiles.

Randomness: a kernel that samples takes a 64-bit `seed` (drawn by the caller from the chunk's
numpy Generator) and runs its own SplitMix64 stream from it (`uniform`; cheaper than numba's
Mersenne Twister), so results depend only on the seed, never on the thread.

Conventions: directions world space, unit; SH basis and frames as `core.sh` (`sh_basis` is
`sh.basis` compiled, the function `sh.evaluate` uses; `local_to_world` applies
`sh.tangent_frames`, the tests compare them; `add_pass` takes I_z from `sh.zonal_band1`).
Nothing here compiles until `get()` is first called: numba is imported lazily (`deps`).
"""

from __future__ import annotations

import math
import threading
from types import SimpleNamespace

import numpy as np

from . import deps, sh

_Y00 = sh.Y00
_C1 = sh.C1
_IRRADZ_FROM_R10 = sh.IRRADZ_FROM_R10
_INV_PI = 1.0 / math.pi
_TWO_PI = 2.0 * math.pi


# ---- helpers (compiled first, so the kernels call the compiled versions) -------------------
def uniform(state):
    """SplitMix64 (Steele et al. 2014): the next state and a uniform float in [0, 1) from its
    top 53 bits. state is a numpy uint64."""
    state = state + np.uint64(0x9E3779B97F4A7C15)
    z = state
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return state, float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


def radical_inverse(i):
    """Van der Corput's radical inverse of i in base 2: its binary digits mirrored about the point."""
    out = 0.0
    scale = 0.5
    while i > 0:
        if i & 1:
            out += scale
        i >>= 1
        scale *= 0.5
    return out


#: The 9 real SH basis values at direction (x, y, z), as a tuple (not array arguments: a view
#: per call costs more than the arithmetic); `get()` rebinds both to their compiled versions.
sh_basis = sh.basis
zonal_band1 = sh.zonal_band1


def local_to_world(nx, ny, nz, lx, ly, lz):
    """Local (lx, ly, lz), z along the unit normal n, to world space (a tuple), in the frame
    of `sh.tangent_frames` (Duff et al. 2017)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (
        lx * (1.0 + sign * nx * nx * a) + ly * b + lz * nx,
        lx * (sign * b) + ly * (sign + ny * ny * a) + lz * ny,
        lz * nz - (lx * sign * nx + ly * ny),
    )


# ---- kernels ---------------------------------------------------------------------------------
def hemisphere_rays(normals, k, seed):
    """k directions per texel over the hemisphere of its unit normal (normals (n, 3)), in two
    independent halves of k/4 uniform then k/4 cosine-weighted samples; each group of k/4
    Latin-hypercube stratified in (u1, u2). Returns directions (n·k, 3) and the mixture pdf
    per steradian (n·k,) = ½/(2π) + ½·cosθ/π (why: the tracer's module docstring)."""
    state = np.uint64(seed)
    n = normals.shape[0]
    q = k // 4
    dirs = np.empty((n * k, 3))
    pdf = np.empty(n * k)
    perm = np.empty(q, np.int64)
    for t in range(n):
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        for g in range(4):
            for i in range(q):  # a random permutation of 0..q-1
                state, u = uniform(state)
                j = min(int(u * (i + 1)), i)
                perm[i] = perm[j]
                perm[j] = i
            for i in range(q):
                s = t * k + g * q + i
                state, u1 = uniform(state)
                state, u2 = uniform(state)
                u1 = (i + u1) / q
                u2 = (perm[i] + u2) / q
                z = u1 if g % 2 == 0 else math.sqrt(1.0 - u1)
                r = math.sqrt(max(1.0 - z * z, 0.0))
                phi = _TWO_PI * u2
                dirs[s, 0], dirs[s, 1], dirs[s, 2] = local_to_world(nx, ny, nz, r * math.cos(phi), r * math.sin(phi), z)
                pdf[s] = 0.25 * _INV_PI + 0.5 * z * _INV_PI
    return dirs, pdf


def footprint_origins(corner, tri_uv, tri_pos, count, centroid, face_normal, offset, k, footprint, tries, seed):
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
    so a shadow edge across a texel is far less noisy than with independent tries."""
    state = np.uint64(seed)
    n = corner.shape[0]
    out = np.empty((n * k, 3))
    for t in range(n):
        state, shift_x = uniform(state)
        state, shift_y = uniform(state)
        for j in range(k):
            s = t * k + j
            found = False
            for attempt in range(2 * tries):
                width = footprint if attempt < tries else 1.0
                if attempt == 0:
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


def replace_hidden(hidden, k, seed):
    """For k samples per texel (hidden (n·k,) bool, True where a sample's origin is hidden from
    its texel's anchor): the sample each one takes its origin from (n·k,) int, itself when
    visible, else a visible sample of the same texel drawn uniformly (the hidden part of the
    footprint is dropped and the visible part keeps uniform density), -1 when none is visible
    (the caller then uses the anchor)."""
    state = np.uint64(seed)
    n = hidden.shape[0] // k
    out = np.empty(n * k, np.int64)
    visible = np.empty(k, np.int64)
    for t in range(n):
        m = 0
        for j in range(k):
            if not hidden[t * k + j]:
                visible[m] = t * k + j
                m += 1
        for j in range(k):
            s = t * k + j
            if not hidden[s]:
                out[s] = s
            elif m == 0:
                out[s] = -1
            else:
                state, u = uniform(state)
                out[s] = visible[min(int(u * m), m - 1)]
    return out


def advance_paths(
    live,
    acc,
    throughput,
    o,
    d,
    t,
    prim,
    ng,
    tri_albedo,
    row_albedo,
    sky,
    radiance,
    offset,
    roulette,
    max_survival,
    seed,
    back_faces_black=False,
):
    """One wavefront step after a closest-hit query of the rays o + t·d (R, 3), (R,), one row per
    live path: `live` (R,) its sample index, `acc` (R, C) radiance gathered so far (C = 3 per
    light set: RGB of set 0, RGB of set 1, ...), `throughput` (R, 3). A ray that missed (prim < 0)
    adds throughput × `sky` (its row of sky (R, C), or sky[0] for all if sky has one row), its
    path ends and writes acc into `radiance[live]` (R', C) (in place). At a hit: throughput × albedo (`row_albedo` (R, 3) if it has rows, else
    tri_albedo[prim]), the unit normal n facing the ray (surfaces are two-sided; ng (R, 3) is
    Embree's, not unit) and the next origin x = hit + offset·n; then, if `roulette`, the path
    survives with probability p = min(max(throughput), max_survival). A survivor gets a
    cosine-distributed direction around n (pdf cosθ/π) and the weight 1/p for what follows.
    With `back_faces_black`, a hit on the back of a triangle (ng · d > 0: the ray started inside
    a closed mesh or behind a wall's modelled side) ends the path like a miss without sky: the
    light gathered before it stays, nothing more is added there.

    Returns the hits compacted, survivors first: (live, acc, throughput, x, n, directions, pdf,
    weight, s) with s survivors; directions and pdf are set for survivors only, weight (s,).
    The caller adds this vertex's light for every hit, then ends the rows from s on (roulette
    decided before but applied after the vertex's light: its victims keep that light too)."""
    state = np.uint64(seed)
    r = o.shape[0]
    cols = acc.shape[1]
    per_row_sky = sky.shape[0] == r and r > 1
    per_row_albedo = row_albedo.shape[0] > 0
    tp = np.empty((r, 3))
    survive = np.zeros(r)  # 0: missed; > 0 survives with it; < 0: roulette victim
    survivors = 0
    victims = 0
    for i in range(r):
        if prim[i] < 0:
            s = i if per_row_sky else 0
            for c in range(cols):
                radiance[live[i], c] = acc[i, c] + throughput[i, c % 3] * sky[s, c]
            continue
        if back_faces_black and ng[i, 0] * d[i, 0] + ng[i, 1] * d[i, 1] + ng[i, 2] * d[i, 2] > 0.0:
            for c in range(cols):  # the back of a surface: the path ends, carrying no more light
                radiance[live[i], c] = acc[i, c]
            continue
        for c in range(3):
            albedo = row_albedo[i, c] if per_row_albedo else tri_albedo[prim[i], c]
            tp[i, c] = throughput[i, c] * albedo
        p = 1.0
        if roulette:
            p = min(max(tp[i, 0], tp[i, 1], tp[i, 2]), max_survival)
            state, u = uniform(state)
            if u >= p:
                p = -1.0
        survive[i] = p
        if p > 0.0:
            survivors += 1
        else:
            victims += 1
    m = survivors + victims
    out_live = np.empty(m, live.dtype)
    out_acc = np.empty((m, cols))
    out_tp = np.empty((m, 3))
    x = np.empty((m, 3))
    n = np.empty((m, 3))
    nd = np.zeros((m, 3))
    pdf = np.zeros(m)
    weight = np.empty(survivors)
    js, jv = 0, survivors
    for i in range(r):
        if survive[i] == 0.0:
            continue
        if survive[i] > 0.0:
            j = js
            js += 1
        else:
            j = jv
            jv += 1
        out_live[j] = live[i]
        for c in range(cols):
            out_acc[j, c] = acc[i, c]
        for c in range(3):
            out_tp[j, c] = tp[i, c]
        gx, gy, gz = float(ng[i, 0]), float(ng[i, 1]), float(ng[i, 2])
        length = math.sqrt(gx * gx + gy * gy + gz * gz)
        if length == 0.0:  # a degenerate triangle: face the ray
            gx, gy, gz, length = d[i, 0], d[i, 1], d[i, 2], 1.0
        scale = 1.0 / length
        if gx * d[i, 0] + gy * d[i, 1] + gz * d[i, 2] > 0.0:
            scale = -scale
        gx, gy, gz = gx * scale, gy * scale, gz * scale
        n[j, 0], n[j, 1], n[j, 2] = gx, gy, gz
        ti = float(t[i])
        x[j, 0] = o[i, 0] + d[i, 0] * ti + gx * offset
        x[j, 1] = o[i, 1] + d[i, 1] * ti + gy * offset
        x[j, 2] = o[i, 2] + d[i, 2] * ti + gz * offset
        if j >= survivors:
            continue
        weight[j] = 1.0 / survive[i]
        state, u1 = uniform(state)
        state, u2 = uniform(state)
        rr = math.sqrt(u1)
        phi = _TWO_PI * u2
        lz = math.sqrt(max(1.0 - u1, 0.0))
        nd[j, 0], nd[j, 1], nd[j, 2] = local_to_world(gx, gy, gz, rr * math.cos(phi), rr * math.sin(phi), lz)
        pdf[j] = lz * _INV_PI
    return out_live, out_acc, out_tp, x, n, nd, pdf, weight, survivors


def project_hemisphere(dirs, radiance, pdf, normals, k):
    """Radiance SH (n, 9, C) of each texel's k samples (directions (n·k, 3), radiance (n·k, C):
    C = 3 per light set, pdf (n·k,) in the group order of `hemisphere_rays`), with a constant
    (per column) as control variate.

    Plain estimate: Σ L Y / (k p) over all k samples (balance heuristic over the two
    strategies: every coefficient, I_z's included, uses every sample). Each half subtracts a
    constant β and adds back its exact integral β·∫Y over the hemisphere of the texel's normal
    (normals (n, 3); ∫Y: band 0 2π·Y00, band 1 π·C1·n, band 2 zero, its basis functions being
    traceless quadratic forms and ∫ ωωᵀ dω = (2π/3)·I over a hemisphere), with β the mean
    radiance of the *other* half's cosine samples: independent of this half's samples, so the
    estimate stays unbiased, and constant radiance is reproduced exactly (the furnace test)
    while near-constant skies lose most of the pdf-shape noise (lower per-texel I_z noise than
    taking I_z from the cosine half alone: README, "Speed vs accuracy")."""
    n = normals.shape[0]
    q = k // 4
    cols = radiance.shape[1]
    out = np.zeros((n, 9, cols))
    beta = np.empty((2, cols))
    for t in range(n):
        base = t * k
        for c in range(cols):
            sa = 0.0
            sb = 0.0
            for i in range(q):
                sa += radiance[base + 3 * q + i, c]  # cosine half B: β for half A
                sb += radiance[base + q + i, c]  # cosine half A: β for half B
            beta[0, c] = sa / q
            beta[1, c] = sb / q
        for j in range(k):
            s = base + j
            h = 0 if j < 2 * q else 1
            w = 1.0 / (pdf[s] * k)
            y = sh_basis(dirs[s, 0], dirs[s, 1], dirs[s, 2])
            for c in range(cols):
                v = (radiance[s, c] - beta[h, c]) * w
                for m in range(9):
                    out[t, m, c] += y[m] * v
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        band0 = _TWO_PI * _Y00
        band1 = _C1 * math.pi
        for c in range(cols):
            b = 0.5 * (beta[0, c] + beta[1, c])
            out[t, 0, c] += band0 * b
            out[t, 1, c] += -band1 * ny * b
            out[t, 2, c] += band1 * nz * b
            out[t, 3, c] += -band1 * nx * b
    return out


def accumulate_grouped(dirs, values, weights, k, out):
    """out[t] += Σ_{s<k} weights[s'] values[s'] Y(dirs[s']), s' = t·k + s: dirs (n·k, 3), values
    (n·k, 3), weights (n·k,), out (n, 9, 3) (in place); dirs and values may be broadcast rows
    (stride 0: a sun's direction and irradiance). Samples of weight 0 cost nothing."""
    for s in range(dirs.shape[0]):
        w = weights[s]
        if w == 0.0:
            continue
        v0, v1, v2 = values[s, 0] * w, values[s, 1] * w, values[s, 2] * w
        y = sh_basis(dirs[s, 0], dirs[s, 1], dirs[s, 2])
        t = s // k
        for m in range(9):
            out[t, m, 0] += y[m] * v0
            out[t, m, 1] += y[m] * v1
            out[t, m, 2] += y[m] * v2


def add_pass(idx, estimate, normals, luminance, total, m2, iz, iz_sq, passes):
    """One pass's SH estimate (len(idx), 9, C) into the running statistics of the texels idx
    (unique), in place: total += estimate; m2 (float32) += (x - mean before)·(x - mean after)
    (Welford, per coefficient; the first pass adds 0); iz / iz_sq += the estimate's I_z (`sh`:
    IRRADZ_FROM_R10 · zonal_band1) weighted by `luminance` (3,) and its square; passes += 1.
    C = 3 per light set: I_z is that of the sets' sum."""
    cols = estimate.shape[2]
    for j in range(idx.shape[0]):
        t = idx[j]
        k = passes[t]
        for m in range(9):
            for c in range(cols):
                x = estimate[j, m, c]
                before = total[t, m, c] / k if k > 0 else x
                total[t, m, c] += x
                m2[t, m, c] += (x - before) * (x - total[t, m, c] / (k + 1))
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        lum = 0.0
        for c in range(cols):
            r10 = zonal_band1(estimate[j, 1, c], estimate[j, 2, c], estimate[j, 3, c], nx, ny, nz)
            lum += luminance[c % 3] * _IRRADZ_FROM_R10 * r10
        iz[t] += lum
        iz_sq[t] += lum * lum
        passes[t] = k + 1


_HELPERS = ("uniform", "radical_inverse", "sh_basis", "zonal_band1", "local_to_world")
_KERNELS = (
    "hemisphere_rays",
    "footprint_origins",
    "replace_hidden",
    "advance_paths",
    "project_hemisphere",
    "accumulate_grouped",
    "add_pass",
)
_compiled: SimpleNamespace | None = None
_lock = threading.Lock()


def get() -> SimpleNamespace:
    """The compiled kernels (numba.njit, nogil, cached on disk), by name. Raises
    DependencyMissing naming numba if it is not installed."""
    global _compiled
    with _lock:
        if _compiled is None:
            numba = deps.require("numba")
            jit = numba.njit(nogil=True, cache=True, error_model="numpy")
            module = globals()
            for name in _HELPERS:  # rebinding the globals: kernels then call compiled helpers
                module[name] = jit(module[name])
            _compiled = SimpleNamespace(**{name: jit(module[name]) for name in _KERNELS})
    return _compiled
