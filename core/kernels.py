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
_BELOW_ONE = 1.0 - 2.0**-53  # the largest double below 1


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


_M32 = np.uint64(0xFFFFFFFF)


def _sobol_second_bytes() -> np.ndarray:
    """(4, 256) uint64: row p, entry x, the XOR of the direction numbers of Sobol's second
    dimension (v_0 = 2^31, v_{j+1} = v_j ^ (v_j >> 1)) of the bits j = 8p + q set in x."""
    v = [1 << 31]
    for _ in range(31):
        v.append(v[-1] ^ (v[-1] >> 1))
    table = np.zeros((4, 256), np.uint64)
    for p in range(4):
        for x in range(256):
            acc = 0
            for q in range(8):
                if x >> q & 1:
                    acc ^= v[8 * p + q]
            table[p, x] = acc
    return table


_SOBOL_SECOND = _sobol_second_bytes()


def sobol_02(i):
    """Point i (< 2^32) of the (0,2)-sequence of Sobol's first two dimensions, as two 32-bit
    integers (uint64) in [0, 2^32): i's bits reversed, and Sobol's second dimension (the XOR
    of its direction numbers over i's set bits, a byte at a time from `_SOBOL_SECOND`). Every
    prefix of 2^m points holds one point in each elementary interval of area 2^-m (Kollig &
    Keller 2002; PBRT's Sobol02)."""
    n = np.uint64(i)
    b = _SOBOL_SECOND[0, n & np.uint64(255)] ^ _SOBOL_SECOND[1, (n >> np.uint64(8)) & np.uint64(255)]
    b ^= (
        _SOBOL_SECOND[2, (n >> np.uint64(16)) & np.uint64(255)]
        ^ _SOBOL_SECOND[3, (n >> np.uint64(24)) & np.uint64(255)]
    )
    return reverse_bits32(n), b


def reverse_bits32(x):
    """x's 32 low bits in reverse order (uint64)."""
    x = ((x >> np.uint64(1)) & np.uint64(0x55555555)) | ((x & np.uint64(0x55555555)) << np.uint64(1))
    x = ((x >> np.uint64(2)) & np.uint64(0x33333333)) | ((x & np.uint64(0x33333333)) << np.uint64(2))
    x = ((x >> np.uint64(4)) & np.uint64(0x0F0F0F0F)) | ((x & np.uint64(0x0F0F0F0F)) << np.uint64(4))
    x = ((x >> np.uint64(8)) & np.uint64(0x00FF00FF)) | ((x & np.uint64(0x00FF00FF)) << np.uint64(8))
    return ((x >> np.uint64(16)) | (x << np.uint64(16))) & _M32


def owen_scramble(x, seed):
    """A nested uniform (Owen) scramble of the 32-bit fraction x (uint64) keyed by `seed`
    (uint64 < 2^32): Laine–Karras's hash on the reversed bits, where each bit only depends on
    the bits above it (Burley 2020). A scrambled net stays a net; each point is uniform."""
    x = reverse_bits32(x)
    x = (x + seed) & _M32
    x ^= (x * np.uint64(0x6C50B47C)) & _M32
    x ^= (x * np.uint64(0xB82F1E52)) & _M32
    x ^= (x * np.uint64(0xC7AFE638)) & _M32
    x ^= (x * np.uint64(0x8D22F6E6)) & _M32
    return reverse_bits32(x)


def sobol_pair(i, key):
    """(u1, u2) in [0, 1): point i (< 2^32) of a (0,2)-sequence keyed by `key` (uint64, e.g.
    `stream_key`): Sobol's first two dimensions (`sobol_02`) at a shuffled index, each
    coordinate Owen-scrambled (`owen_scramble`). The index shuffle is itself a nested scramble
    (Burley 2020), so every aligned block of 2^m indices (a pass, the first 2^j passes) still
    maps to an aligned block, i.e. a (0,m,2)-net; without it, sample j of every pass would
    fall in the same coarse stratum, and two sequences indexed alike (a texel's directions and
    its origins) would pair the same strata in every pass: a texel's error would stop falling."""
    shuffle = stream_key(key, 0, 1) & _M32
    a, b = sobol_02(owen_scramble(np.uint64(i) & _M32, shuffle))
    scale = 1.0 / 4294967296.0
    return float(owen_scramble(a, key & _M32)) * scale, float(owen_scramble(b, key >> np.uint64(32))) * scale


def mixture_cos(u, alpha):
    """cosθ for the uniform number u under the hemisphere mixture α/(2π) + (1 − α)·cosθ/π:
    the root in [0, 1] of α z + (1 − α) z² = u, in the form without cancellation near 0."""
    if u <= 0.0:
        return 0.0
    return 2.0 * u / (alpha + math.sqrt(alpha * alpha + 4.0 * (1.0 - alpha) * u))


def stream_key(seed, texel, stream):
    """A 64-bit state keyed by (seed, texel, stream), decorrelated (SplitMix64 of their mix)."""
    state = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(texel) * np.uint64(0xD1B54A32D192ED03)
    state = state + np.uint64(stream) * np.uint64(0xAEF17502108EF2D9)
    z = (state ^ (state >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


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


#: The first stream number of `texel_hemisphere_rays`' two halves (`stream_key`), apart from
#: the dimensions `texel_sequence` draws for lights.
_DIRECTION_STREAMS = 64
#: The stream number of `footprint_origins`' first tries.
_ORIGIN_STREAM = 96


def texel_hemisphere_rays(normals, k, texels, first, seed, uniform_share):
    """k directions per texel over the hemisphere of its unit normal (normals (n, 3)) drawn
    from the mixture p(ω) = α/(2π) + (1 − α)·cosθ/π (α = uniform_share) by inverting its
    cumulative distribution in cosθ (`mixture_cos`), in two independent halves of k/2 (the
    control variate's, `project_halves`). Each half's (u1, u2) come from its texel's own
    (0,2)-sequence (`sobol_pair`; one per (seed, texel id, half))
    at indices first/2 .. first/2 + k/2 − 1: `first` is the pass's first sample (pass × k),
    so a texel's samples are stratified across all its passes, not only within each.
    texels (n,): the texels' global ids. Returns directions (n·k, 3) and the density per
    steradian (n·k,)."""
    n = normals.shape[0]
    half = k // 2
    start = first // 2
    dirs = np.empty((n * k, 3))
    pdf = np.empty(n * k)
    for t in range(n):
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
        for h in range(2):
            key = stream_key(seed, texels[t], _DIRECTION_STREAMS + h)
            for i in range(half):
                s = t * k + h * half + i
                u1, u2 = sobol_pair(start + i, key)
                z = mixture_cos(u1, uniform_share)
                r = math.sqrt(max(1.0 - z * z, 0.0))
                phi = _TWO_PI * u2
                dirs[s, 0], dirs[s, 1], dirs[s, 2] = local_to_world(nx, ny, nz, r * math.cos(phi), r * math.sin(phi), z)
                pdf[s] = uniform_share * 0.5 * _INV_PI + (1.0 - uniform_share) * z * _INV_PI
    return dirs, pdf


def row_sequence(rows, texels, k, first, seed, stream):
    """(2, R) uniform numbers for rows (R,) of a pass's samples (row t·k + j: sample j of the
    texel texels[t], global id): point first + j of that texel's (0,2)-sequence keyed by
    (seed, texel id, stream) (`sobol_pair`). A texel's rows across all
    its passes (first = pass × k) are stratified together, whichever rows a pass asks for."""
    out = np.empty((2, rows.shape[0]))
    for i in range(rows.shape[0]):
        out[0, i], out[1, i] = sobol_pair(first + rows[i] % k, stream_key(seed, texels[rows[i] // k], stream))
    return out


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


_NO_NUMBERS = np.zeros((2, 0))  # advance_paths without given numbers


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
    survival_power,
    survival_reference,
    seed,
    back_faces_black=False,
    u_dir=_NO_NUMBERS,
):
    """One wavefront step after a closest-hit query of the rays o + t·d (R, 3), (R,), one row per
    live path: `live` (R,) its sample index, `acc` (R, C) radiance gathered so far (C = 3 per
    light set: RGB of set 0, RGB of set 1, ...), `throughput` (R, 3). A ray that missed (prim < 0)
    adds throughput × `sky` (its row of sky (R, C), or sky[0] for all if sky has one row), its
    path ends and writes acc into `radiance[live]` (R', C) (in place). At a hit: throughput × albedo (`row_albedo` (R, 3) if it has rows, else
    tri_albedo[prim]), the unit normal n facing the ray (surfaces are two-sided; ng (R, 3) is
    Embree's, not unit) and the next origin x = hit + offset·n; then, if `roulette`, the path
    survives with probability p = min((max(throughput) / survival_reference)^survival_power,
    max_survival): a path whose throughput is at least the reference is kept (with max_survival
    1), and a power below 1 ends fewer of the others than their throughput alone. A survivor gets a
    cosine-distributed direction around n (pdf cosθ/π) and the weight 1/p for what follows.
    With `back_faces_black`, a hit on the back of a triangle (ng · d > 0: the ray started inside
    a closed mesh or behind a wall's modelled side) ends the path like a miss without sky: the
    light gathered before it stays, nothing more is added there. u_dir (2, R), if it has
    columns: the uniform numbers of each row's new direction (else drawn from `seed`'s stream).

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
            p = min((max(tp[i, 0], tp[i, 1], tp[i, 2]) / survival_reference) ** survival_power, max_survival)
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
        if u_dir.shape[1] > 0:
            u1, u2 = u_dir[0, i], u_dir[1, i]
        else:
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
    return _project_control_variate(dirs, radiance, pdf, normals, k, k // 4, k // 4)


def project_halves(dirs, radiance, pdf, normals, k):
    """`project_hemisphere` for samples in two independent halves of k/2 (`texel_hemisphere_rays`):
    each half subtracts β = the mean radiance of the *other* half and adds back β·∫Y."""
    return _project_control_variate(dirs, radiance, pdf, normals, k, 0, k // 2)


def _project_control_variate(dirs, radiance, pdf, normals, k, offset, count):
    """`project_hemisphere`'s estimator with each half's β the mean radiance of the other
    half's samples offset .. offset + count − 1 (counted from that half's start)."""
    n = normals.shape[0]
    half = k // 2
    cols = radiance.shape[1]
    out = np.zeros((n, 9, cols))
    beta = np.empty((2, cols))
    band0 = _TWO_PI * _Y00
    band1 = _C1 * math.pi
    for t in range(n):
        base = t * k
        for c in range(cols):
            sa = 0.0
            sb = 0.0
            for i in range(count):
                sa += radiance[base + half + offset + i, c]  # half B: β for half A
                sb += radiance[base + offset + i, c]  # half A: β for half B
            beta[0, c] = sa / count
            beta[1, c] = sb / count
        for j in range(k):
            s = base + j
            h = 0 if j < half else 1
            w = 1.0 / (pdf[s] * k)
            y = sh_basis(dirs[s, 0], dirs[s, 1], dirs[s, 2])
            for c in range(cols):
                v = (radiance[s, c] - beta[h, c]) * w
                for m in range(9):
                    out[t, m, c] += y[m] * v
        nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
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


def _unit3(x, y, z):
    """(x, y, z) / its length (NaN for a zero vector)."""
    inv = 1.0 / math.sqrt(x * x + y * y + z * z)
    return x * inv, y * inv, z * inv


def _spherical(x, i, triangles, t):
    """Seen from x[i] (of (R, 3)), triangle triangles[t] (T, 3, 3): unit directions a, b, c
    (3-tuples) to its corners, the cosine and sine of the angle at a and the solid angle
    (`lights.spherical_triangles`, one row; 0 seen edge-on, NaN from a corner)."""
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
    (Arvo 1995, as `lights.sample_spherical_triangles`)."""
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
    """One emitter sample per point x (R, 3) (`lights.EmissiveTriangles._sample_points`, one
    row at a time): a leaf of the light tree by `u[0]` (`_pick_leaf`, with normals (R, 3) or
    no rows), the triangle of the leaf by `u[1]` (the first of its rows of `key` above leaf +
    u), then, if its solid angle from x lies in window (lo, hi), a direction in it by u[2], u[3]
    (`_spherical_direction`), else a uniform point on it. u (4, R); emitters: (clusters (10,
    K): the tree's K nodes, rows as `_cluster_weights` takes them; key (E,), order (E,),
    first (K,), last (K,): each leaf's rows of key; each triangle's bounding sphere (T, 4):
    centre, radius; child_first, child_count (K + 1,), parent (K,): `lights.light_tree`).
    Returns directions (R, 3), distances (R,), triangles (R,) int64 and densities (R,)."""
    clusters, key, order, first, last, bound, child_first, child_count, _ = emitters
    n = x.shape[0]
    horizon = normals.shape[0] > 0
    dirs = np.empty((n, 3))
    dist = np.empty(n)
    pick = np.empty(n, np.int64)
    pdf = np.empty(n)
    w = np.empty(clusters.shape[1])
    for i in range(n):
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


#: Bases of the radical inverses of `texel_sequence`'s dimensions (Halton's first primes).
_PRIMES = np.array([2, 3, 5, 7, 11, 13, 17, 19], np.int64)


def _spherical_rectangle(px, py, pz, rect, u1, u2):
    """Seen from (px, py, pz), the rectangle rect (4, 3) (its corner, unit edges ax and ay and
    az = ax × ay) with edge lengths (exl, eyl) in rect[3, 0:2]: a point on it (3-tuple) whose
    direction is uniform in its solid angle for uniform numbers u1, u2, and that solid angle
    (0 from its plane). `lights.sample_spherical_rectangles`, one row: the four corner angles
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
    """One sample per point x (R, 3) of an area light (`lights.Area.sample`, one row at a time):
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


def texel_sequence(texels, k, first, dim, seed):
    """(n·k,) numbers in [0, 1): for each texel of texels (n,) (global ids) its samples first ..
    first + k − 1 of dimension dim of a Halton sequence (radical inverse in base _PRIMES[dim])
    shifted modulo 1 by a random offset per (seed, texel, dim) (Cranley–Patterson rotation):
    every number is uniform, a texel's samples are stratified across all its passes, and the
    offsets make texels and seeds independent."""
    base = _PRIMES[dim % _PRIMES.shape[0]]
    inv = 1.0 / base
    out = np.empty(texels.shape[0] * k)
    for t in range(texels.shape[0]):
        state = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(texels[t]) * np.uint64(0xD1B54A32D192ED03)
        state = state + np.uint64(dim) * np.uint64(0xAEF17502108EF2D9)
        state, shift = uniform(state)
        for j in range(k):
            i = first + j
            v = 0.0
            f = inv
            while i > 0:
                v += (i % base) * f
                i //= base
                f *= inv
            v += shift
            out[t * k + j] = v - 1.0 if v >= 1.0 else v
    return out


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
    factor is kept). clusters (10, K): rows centre x, y, z, radius², radius, power, the lone
    triangle's id in triangles (T, 3, 3) (−1: several), its luminance, the near distance², the
    distance² from which the tree below is descended by power alone (`_pick_leaf`).
    Element-wise and branch-free, so the first loops vectorise (bit for bit the scalar
    arithmetic; without fast-math, which would reassociate the sum and make its last bits
    depend on the arrays' alignment: a seed would no longer reproduce a bake bit for bit
    across processes). Scalars and three arrays: a call's cost grows with its arguments.
    With d the distance, r the radius and a = normal · (centre − x): the normal lies inside
    the cone of directions into the sphere when a ≥ √(d² − r²), else the nearest edge's
    cosine is (a √(d² − r²) + √(d² − a²) r) / d²; inside the sphere, 1."""
    near = 0
    if horizon:
        for c in range(first, end):
            dx, dy, dz = clusters[0, c] - px, clusters[1, c] - py, clusters[2, c] - pz
            d2 = dx * dx + dy * dy + dz * dz
            near += d2 < clusters[8, c]
            r2 = clusters[3, c]
            a = nx * dx + ny * dy + nz * dz
            h2 = d2 - r2
            edge = a * math.sqrt(max(h2, 0.0)) + math.sqrt(max(d2 - a * a, 0.0)) * clusters[4, c]  # × d2
            outside = (h2 > 0.0) & ((a < 0.0) | (a * a < h2))
            d2s = max(d2, 1e-300)
            w[c] = clusters[5, c] * (max(edge, 0.0) if outside else d2s) / (max(d2, r2) * d2s)
    else:
        for c in range(first, end):
            dx, dy, dz = clusters[0, c] - px, clusters[1, c] - py, clusters[2, c] - pz
            d2 = dx * dx + dy * dy + dz * dz
            near += d2 < clusters[8, c]
            w[c] = clusters[5, c] / max(d2, clusters[3, c])
    for c in range(first, end if near else first):  # lone triangles near x: by solid angle
        if clusters[6, c] < 0.0 or w[c] <= 0.0:
            continue
        dx, dy, dz = clusters[0, c] - px, clusters[1, c] - py, clusters[2, c] - pz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < clusters[8, c]:
            omega = _solid_angle(px, py, pz, triangles, int(clusters[6, c]))
            if math.isfinite(omega):  # NaN from a corner: keep the distance's weight
                w[c] *= clusters[7, c] * omega * max(d2, clusters[3, c]) / clusters[5, c]
    total = 0.0
    for c in range(first, end):
        total += w[c]
    return total


def _child_chance(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, first, end, share):
    """(scale, mix, power) of the choice among the light tree nodes first .. end − 1 (siblings)
    at (px, py, pz): node c is picked with probability scale·w[c] + mix·clusters[5, c] / power
    (`_cluster_weights` into w, `_cluster_chances`; power: the siblings' summed power)."""
    total = _cluster_weights(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, first, end)
    scale, mix = _cluster_chances(total, share)
    return scale, mix, _power_of(clusters, first, end)


def _pick_leaf(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, child_first, child_count, u, share):
    """(leaf, chance): a leaf of the light tree (`lights.light_tree`: child_first, child_count
    (N + 1,), the last entry the root) picked at (px, py, pz) by the uniform number u, one level
    at a time among a node's children (`_child_chance`), u rescaled to the picked child's
    interval for the next level; below a node the point lies far from (distance² at least its
    clusters[9]), by power alone (`_power_of`): its leaves' weights would differ little.
    chance: the product of the levels' probabilities."""
    node = child_first.shape[0] - 1
    chance = 1.0
    far = False
    while child_count[node] > 0:
        a, end = child_first[node], child_first[node] + child_count[node]
        if end - a == 1:
            node = a
            continue
        if far:
            scale, mix, power = 0.0, 1.0, _power_of(clusters, a, end)
        else:
            scale, mix, power = _child_chance(px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, a, end, share)
        pick, below, acc = end - 1, 0.0, 0.0
        for c in range(a, end):
            below = acc
            acc += (scale * w[c] if scale > 0.0 else 0.0) + mix * (clusters[5, c] / power)
            if u < acc:
                pick = c
                break
        p = (scale * w[pick] if scale > 0.0 else 0.0) + mix * (clusters[5, pick] / power)
        chance *= p
        u = min(max((u - below) / p, 0.0), _BELOW_ONE) if p > 0.0 else 0.0
        node = pick
        far = far or _far_from(px, py, pz, clusters, node)
    return node, chance


def _power_of(clusters, first, end):
    """The summed power of the light tree nodes first .. end − 1."""
    power = 0.0
    for c in range(first, end):
        power += clusters[5, c]
    return power


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
                chance *= clusters[5, c] / _power_of(clusters, a, end)
            else:
                scale, mix, power = _child_chance(
                    px, py, pz, nx, ny, nz, horizon, clusters, triangles, w, a, end, share
                )
                chance *= scale * w[c] + mix * (clusters[5, c] / power)
        node = c
        far = far or _far_from(px, py, pz, clusters, node)
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
    """Which one light of `table` (L, 13) each point x (R, 3) samples (`lights.Choice`), by its
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


_HELPERS = (
    "uniform",
    "radical_inverse",
    "reverse_bits32",
    "sobol_02",
    "owen_scramble",
    "stream_key",
    "sobol_pair",
    "mixture_cos",
    "_project_control_variate",
    "sh_basis",
    "zonal_band1",
    "local_to_world",
    "_solid_angle",
    "_cluster_weights",
    "_normal",
    "_cluster_chances",
    "_power_of",
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
_ALLOCATING = ("_project_control_variate",)  # helpers that make arrays (need reference counts)
_KERNELS = (
    "sample_emitters",
    "sample_area_light",
    "choose_lights",
    "emitter_pdf",
    "texel_sequence",
    "hemisphere_rays",
    "texel_hemisphere_rays",
    "row_sequence",
    "footprint_origins",
    "replace_hidden",
    "advance_paths",
    "project_hemisphere",
    "project_halves",
    "accumulate_grouped",
    "add_pass",
    "near_box",
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
            # helpers that make no array are compiled without reference counting: otherwise every
            # call (per sample) counts each array it is passed up and down, atomically
            borrow = numba.njit(nogil=True, cache=True, error_model="numpy", _nrt=False)
            module = globals()
            for name in _HELPERS:  # rebinding the globals: kernels then call compiled helpers
                module[name] = (jit if name in _ALLOCATING else borrow)(module[name])
            _compiled = SimpleNamespace(**{name: jit(module[name]) for name in _KERNELS})
    return _compiled
