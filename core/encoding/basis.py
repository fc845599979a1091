"""Coefficient encodings (Baking Lab's set: SH, HL2, H-basis, SG): the shared interface. No bpy.

A coefficient encoding stores K RGB layers per texel, computed from the texel's traced radiance
SH (L2, world space, over the hemisphere of n_v: docs/conventions.md#what-the-sh-store). Its
module (`sh_l1`, `sh_l2`, `hl2`, `hbasis_l1`, `hbasis_l2`, `sg5` … `sg12`) has, besides the
registry's `FILE` and `encoding(settings)`, `basis(settings=None) -> Basis`: the math, which
later code (preview, compare, docs/format.md's HLSL) mirrors:

    coefficients(sh (N, 9, 3), n_v (N, 3))            -> (N, K, 3)  what the file's layers hold
    irradiance(c (N, K, 3), n_v, n (N, 3))            -> (N, 3)     I(n), docs/conventions.md#irradiance-units
    specular(c, n_v, n, v (N, 3), alpha, f0=1.0)      -> (N, 3)     S(n, v; α, F0) (`ggx`), or
                                                                    NotImplementedError if `SPECULAR` is False

n is the shading normal, v the unit direction to the viewer, both world space; α is GGX's α.
Encodings in a **tangent frame** (HL2, H-basis, SG) use `frames(n_v)` = `core.sh.tangent_frames`
(Duff et al. 2017: t = (1 + s n_x² a, s n_x n_y a, −s n_x), b = (n_x n_y a, s + n_y² a, −n_y),
s = +1 if n_z ≥ 0 else −1, a = −1/(s + n_z)); a runtime must build the same frame from the same
n_v. That frame flips (t_z, b_x… change sign) where n_z crosses 0: coefficients of texels on
either side are in different frames and must not be blended (docs/format.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .. import sh as _sh
from ..colour import LUMINANCE
from .spec import DILATE_BURIED_BLACK, HALF_OR_FLOAT, Channel, Encoded, FileSpec


class Basis(Protocol):
    """The math of one coefficient encoding (see the module docstring)."""

    name: str
    count: int
    SPECULAR: bool

    def coefficients(self, sh: np.ndarray, n_v: np.ndarray) -> np.ndarray: ...

    def irradiance(self, c: np.ndarray, n_v: np.ndarray, n: np.ndarray) -> np.ndarray: ...

    def specular(self, c: np.ndarray, n_v: np.ndarray, n: np.ndarray, v: np.ndarray, alpha, f0=1.0) -> np.ndarray: ...


def frames(n_v: np.ndarray) -> np.ndarray:
    """The tangent frames `(N, 3, 3)` (columns t, b, n_v) the tangent-space encodings use."""
    return _sh.tangent_frames(np.asarray(n_v, np.float64))


def to_frame(f: np.ndarray, d: np.ndarray) -> np.ndarray:
    """World vectors `d (N, 3)` in the frames `f (N, 3, 3)` -> `(N, 3)`."""
    return np.einsum("nij,ni->nj", f, d)


def fibonacci_hemisphere(count: int) -> np.ndarray:
    """`count` unit directions `(count, 3)` over the upper hemisphere (z ≥ 0), equal solid angle
    each (2π/count): Fibonacci spiral, z = 1 − (i + ½)/count."""
    i = np.arange(count) + 0.5
    z = 1.0 - i / count
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def layers(prefix: str, count: int, meaning: str, preview: str) -> tuple[Channel, ...]:
    """`count` RGB layers `<prefix>0` … (half, or float32 beyond half's range), filled like I_z,
    each shown by the preview image `<preview>_<k>` (the encoding's file key: the Encoded
    preview mode, `files.preview`; unique across encodings, so a re-encode into another
    model never overwrites one another model's sidecar could name)."""
    return tuple(
        Channel(
            f"{prefix}{k}", tuple("RGB"), HALF_OR_FLOAT, meaning, fill=DILATE_BURIED_BLACK, preview=f"{preview}_{k}"
        )
        for k in range(count)
    )


@dataclass
class CoefficientEncoding:
    """The Encoding (`spec.Encoding`) of a Basis into `file` (its K layers in order);
    `settings`: what the sidecar records under `encoder`."""

    basis: Basis
    file: FileSpec
    settings: dict = field(default_factory=dict)

    def encode(self, sh: np.ndarray, n_v: np.ndarray) -> Encoded:
        """Each layer `(N, 3)` float64; stats: the largest |coefficient|, the sum of the
        luminance of I(n_v) as reconstructed (for its mean), fits left inexact."""
        sh = np.asarray(sh, np.float64)
        n_v = np.asarray(n_v, np.float64)
        solve = getattr(self.basis, "solve_coefficients", None)
        c, unsolved = solve(sh, n_v) if solve is not None else (self.basis.coefficients(sh, n_v), 0)
        c = np.where(np.isfinite(c), c, 0.0)
        values = {ch.name: c[:, k] for k, ch in enumerate(self.file.channels)}
        iz = self.basis.irradiance(c, n_v, n_v) if len(c) else np.zeros((0, 3))
        stats = {
            "coefficient_max_abs": float(np.abs(c).max(initial=0.0)),
            "irradz_luminance_sum": float((iz @ LUMINANCE).sum()),
            "unsolved": int(unsolved),
        }
        return Encoded(values, stats)

    def summary(self, stats: list[dict], texels: int) -> dict:
        """coefficient_max_abs, irradz_mean_luminance (I(n_v) of the reconstruction) and
        solve_unsolved: (texel, colour) fits an iterative solve left inexact (SG NNLS)."""
        top, lum, unsolved = 0.0, 0.0, 0
        for s in stats:
            top = max(top, s["coefficient_max_abs"])
            lum += s["irradz_luminance_sum"]
            unsolved += s["unsolved"]
        return {
            "coefficient_max_abs": top,
            "irradz_mean_luminance": lum / texels if texels else 0.0,
            "solve_unsolved": unsolved,
        }
