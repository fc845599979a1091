"""`encode`: HHD / AHD parameters of world-space radiance SH, per texel, in chunks. No bpy.

Per chunk of CHUNK texels: sanitise (non-finite texels marked invalid and zeroed, normals
normalised, float64), rotate into the frame z = n_v and set up the fit (`fit.prepare`), start
from the optimal linear direction, search (`search`), and rotate the direction back to world space.
"""

from __future__ import annotations

import numpy as np

from .. import gram as _gram
from .fit import prepare
from .lobes import MIN_COS, HHDParams, ambient_lobe
from .search import GOLDEN_ITERATIONS, optimal_linear_angles, search_phi, search_theta

#: Texels per chunk: the fit's (N,) temporaries stay small, and its numpy calls few enough that
#: the encoder's workers (`encoding.stage.encode_images`: chunk-parallel threads) do not queue on
#: the GIL between them. Every step is per texel, so the values do not depend on it.
CHUNK = 32768


def check_shapes(sh, n_v) -> None:
    shape, n_shape = np.shape(sh), np.shape(n_v)
    if len(shape) not in (2, 3) or shape[1] != 9:
        raise ValueError(f"sh must have shape (N, 9, C), got {shape}")
    if n_shape != (shape[0], 3):
        raise ValueError(f"n_v must have shape ({shape[0]}, 3), got {n_shape}")


def sanitise(sh: np.ndarray, n_v: np.ndarray):
    """float64 copies `(N, 9, C)`, `(N, 3)` with non-finite rows zeroed and normals normalised;
    plus the invalid mask `(N,)` bool."""
    check_shapes(sh, n_v)
    sh = np.asarray(sh, dtype=np.float64)
    n_v = np.asarray(n_v, dtype=np.float64)
    if sh.ndim == 2:
        sh = sh[..., None]
    with np.errstate(invalid="ignore", over="ignore"):
        length = np.linalg.norm(n_v, axis=1)
    invalid = ~np.isfinite(sh).all(axis=(1, 2)) | ~np.isfinite(length) | (length < 1e-12)
    if invalid.any():
        sh = sh.copy()
        sh[invalid] = 0.0
    safe_len = np.where(invalid, 1.0, length)
    n_v = np.where(invalid[:, None], np.array([0.0, 0.0, 1.0]), n_v / safe_len[:, None])
    return sh, n_v, invalid


def gram_matrix(gram: str) -> np.ndarray:
    """`(9, 9)` Gram matrix of the fit: "hemisphere" or "sphere"."""
    return _gram.hemisphere() if gram == "hemisphere" else _gram.sphere()


def encode(
    sh,
    n_v,
    model: str = "hhd",
    direction: str = "searched",
    gram: str = "hemisphere",
    ambient: str = "luminance",
    *,
    hemisphere_sampled: bool = True,
    phi_search: bool = False,
    min_cos: float = MIN_COS,
    golden_iterations: int = GOLDEN_ITERATIONS,
) -> HHDParams:
    """Fit HHD or AHD to world-space radiance SH, per texel.

    sh   `(N, 9, C)` world-space radiance SH (any float dtype; C = 3 for RGB)
    n_v  `(N, 3)` vertex normals (normalised here)
    model "hhd" | "ahd";  direction "searched" | "optimal_linear";  gram "hemisphere" | "sphere";
    ambient "luminance" (one w_a fitted to the luminance, as the 2018 paper's L(C_a)/L(I_z)) |
    "rgb" (w_a per channel).
    hemisphere_sampled: True (default) for a lightmap bake, whose SH holds radiance over the
    hemisphere of n_v only: I_z = 2/√(3π) r_1^0 exactly. Pass False for full-sphere SH (a probe):
    I_z = Y(n_v)·i, the SH irradiance, clamped to ≥ 0 (clamps counted in `clamped_irradz`). The
    target of the fit is the SH irradiance i either way.
    phi_search: add the outer φ search (many times the cost for a slight error decrease: docs/encoder.md).
    min_cos: floor on d·n_v.
    golden_iterations: golden-section steps of the θ search (each shrinks the bracket by 0.618;
    0 keeps the best of the coarse scan and the optimal-linear θ).

    NaN/Inf in a texel's SH or normal, or a zero normal, marks it `invalid` and encodes it
    black rather than raising: one bad texel must not lose a bake. Callers report `n_invalid`.
    Output never contains NaN or Inf.
    """
    if direction not in ("searched", "optimal_linear"):
        raise ValueError(f"direction must be 'searched' or 'optimal_linear', not {direction!r}")
    if gram not in ("hemisphere", "sphere"):
        raise ValueError(f"gram must be 'hemisphere' or 'sphere', not {gram!r}")
    if ambient not in ("luminance", "rgb"):
        raise ValueError(f"ambient must be 'luminance' or 'rgb', not {ambient!r}")
    options = dict(
        a=ambient_lobe(model),
        g=gram_matrix(gram),
        searched=direction == "searched",
        luminance=ambient == "luminance",
        hemisphere_sampled=hemisphere_sampled,
        phi_search=phi_search,
        theta_max=float(np.arccos(min_cos)),
        iterations=max(0, int(golden_iterations)),
    )
    check_shapes(sh, n_v)
    parts = [
        encode_chunk(*sanitise(sh[s : s + CHUNK], n_v[s : s + CHUNK]), **options) for s in range(0, len(n_v), CHUNK)
    ] or [encode_chunk(*sanitise(sh, n_v), **options)]
    iz, w, d, clamped, invalid = (np.concatenate(x) for x in zip(*parts))
    return HHDParams(irradz=iz, ambient_weight=w, direction=d, model=model, invalid=invalid, clamped_irradz=clamped)


def encode_chunk(world_sh, n, invalid, *, searched, phi_search, theta_max, iterations, **prepare_options):
    """encode() on one chunk of sanitised texels -> (I_z, w_a, d_world, clamped, invalid)."""
    fit, frames, local, iz, clamped, lum_fit = prepare(world_sh, n, **prepare_options)
    theta, phi = optimal_linear_angles(local, lum_fit, theta_max)
    at = fit.at_phi(phi)  # the products at φ: made once for the θ search and the final fit
    if searched:
        if phi_search:
            theta, phi = search_phi(fit, phi, theta, theta_max, iterations)
            at = fit.at_phi(phi)
            _, w = at.evaluate(theta)
        else:
            theta, _, w = search_theta(fit, phi, theta, theta_max, iterations, at=at)
    else:
        _, w = at.evaluate(theta)
    # Where the fit is all ambient (w = 1 up to rounding) the direction is irrelevant: store
    # n_v, which keeps the direction texture smooth for filtering.
    all_ambient = (w >= 1.0 - 1e-9).all(axis=1)
    theta = np.where(all_ambient, 0.0, theta)
    w = np.where(all_ambient[:, None], 1.0, w)

    st = np.sin(theta)
    d_local = np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=1)
    d_world = np.einsum("nij,nj->ni", frames, d_local)
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    return iz, (w[:, 0] if prepare_options["luminance"] else w), d_world, clamped, invalid
