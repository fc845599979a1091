"""Sampling sequences, compiled (numba) for the tracer and the bake points. No bpy.

Randomness: a kernel that samples takes a 64-bit `seed` (drawn by the caller from the chunk's
numpy Generator) and runs its own SplitMix64 stream from it (`uniform`; cheaper than numba's
Mersenne Twister), so results depend only on the seed, never on the thread. Stratified numbers
come from Owen-scrambled (0,2)-sequences keyed per (seed, texel, stream) (`sobol_pair`,
`row_sequence`) and from Cranley–Patterson-rotated Halton dimensions (`texel_sequence`), so a
texel's samples are stratified across all its passes. `local_to_world` applies the frames of
`sh.tangent_frames` (the tests compare them). The helpers are plain Python until `get()` (`core.compiled`)
compiles them; the kernel modules that import them call the compiled versions.
"""

from __future__ import annotations

import math

import numpy as np

from . import compiled


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


def row_sequence(rows, texels, k, first, seed, stream):
    """(2, R) uniform numbers for rows (R,) of a pass's samples (row t·k + j: sample j of the
    texel texels[t], global id): point first + j of that texel's (0,2)-sequence keyed by
    (seed, texel id, stream) (`sobol_pair`). A texel's rows across all
    its passes (first = pass × k) are stratified together, whichever rows a pass asks for."""
    out = np.empty((2, rows.shape[0]))
    for i in range(rows.shape[0]):
        out[0, i], out[1, i] = sobol_pair(first + rows[i] % k, stream_key(seed, texels[rows[i] // k], stream))
    return out


#: Bases of the radical inverses of `texel_sequence`'s dimensions (Halton's first primes).
_PRIMES = np.array([2, 3, 5, 7, 11, 13, 17, 19], np.int64)


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


KERNELS = compiled.KernelSet(
    __name__,
    kernels=("row_sequence", "texel_sequence"),
    helpers=(
        "uniform",
        "radical_inverse",
        "reverse_bits32",
        "sobol_02",
        "owen_scramble",
        "stream_key",
        "sobol_pair",
        "mixture_cos",
        "local_to_world",
    ),
)
get = KERNELS.get
