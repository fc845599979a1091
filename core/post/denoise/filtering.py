"""A page through OIDN's lightmap filter: its SH as features (L0 and I_z as HDR colour, the rest
of band 1 and band 2 in luminance: `_page_features`), filled and filtered (`_denoise_features`:
`_hdr` with its exposure and energy correction, `_directional` over the denoised L0), and back
to SH (`_assemble`); the process's `Denoiser`s (`denoiser_for`). No bpy."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...colour import LUMINANCE
from ...sh import IRRADZ_FROM_R10
from .fill import _smooth_fill
from .noise_clamp import WRITE_CHUNK
from .oidn import Denoiser

#: The directional coefficients are scaled into ±DIRECTIONAL_RANGE (of OIDN's [-1, 1]) for
#: radiance ≥ 0; the rest of the range is headroom for the noise (Unreal uses 0.5).
DIRECTIONAL_RANGE = 0.5
#: |c / c_0| bound of an SH coefficient for any radiance ≥ 0 (max |Y| / Y_00), per band.
BAND1_BOUND, BAND2_BOUND = math.sqrt(3.0), math.sqrt(5.0)
#: L0 and I_z go through the filter raised to this power (`_hdr_filtered`), and are raised back
#: after: a compressed range, in which a chart's darkest texels next to its brightest ones (a
#: sunlit strip beside a shadowed face, both a texel wide) take less of their light. The per-page
#: energy correction restores the mean the power's curvature takes (bench/results).
HDR_POWER = 0.7
#: Bound of the per-page energy correction of the HDR channels (`_hdr`).
ENERGY_CLAMP = 1.5
#: OIDN's auto-exposure key value (its `autoexposure` op): inputScale = KEY / geometric-mean luminance.
KEY = 0.18
#: The features (`_page_features`) each pass over a banded page builds: all (the fill's page
#: mean), L0 and I_z (filtered as HDR colour), the rest (filtered in directional mode).
ALL, HDR, DIRECTIONAL = slice(0, 14), slice(0, 6), slice(6, 14)
#: Rows of a band's features built at once (`_denoise_banded`): bounds the SH image and the
#: temporaries `_page_features` makes (several times the features' own 112 bytes a texel).
FEATURE_ROWS = 32


def input_scale(colour: np.ndarray) -> float:
    """OIDN's auto-exposure over HDR colours `(T, 3)` (a page's texels): KEY over the geometric
    mean luminance of the non-black ones (1 if all are black)."""
    return _scale_of_luminance(colour @ LUMINANCE)


def _scale_of_luminance(lum: np.ndarray) -> float:
    """`input_scale` of the luminances `lum` (T,)."""
    lum = lum[lum > 1e-8]
    if not len(lum):
        return 1.0
    return float(KEY / np.exp2(np.mean(np.log2(lum.astype(np.float64)))))


def _page_features(values: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One page's inputs to the filter (`_denoise_features`), from its SH `(h, w, 9, 3)` and unit
    n_v `(h, w, 3)`: `(h, w, 14)` float64: L0 (RGB), I_z (RGB), band 1 across n_v and band 2
    (luminance); and the unit n_v `(h, w, 3)` float64."""
    n = normal.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    v = _band1_vector(values[:, :, :4]).astype(np.float64)  # (h, w, 3 axes, 3 colours); exact: a sign and a cast
    along = np.einsum("hwa,hwac->hwc", n, v)
    v -= n[..., None] * along[:, :, None, :]  # in place: v is not needed any more
    across = np.einsum("hwac,c->hwa", v, LUMINANCE)
    del v
    features = np.concatenate(
        [values[:, :, 0, :], IRRADZ_FROM_R10 * np.maximum(along, 0.0), across, values[:, :, 4:, :] @ LUMINANCE],
        axis=-1,
    )
    return features, n


def _denoise_features(
    features: np.ndarray,
    n: np.ndarray,
    source: np.ndarray,
    denoiser: Denoiser,
    scales: tuple[float, float],
    at: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """One page denoised from its `_page_features` (consumed: filled in place), meaningful at its
    chart texels `source`: they are filled smoothly elsewhere (`_smooth_fill`), then L0 and I_z
    are denoised as HDR colour (`scales`: their inputScale) and the rest in directional mode over
    the denoised L0 (module docstring). Returns `(h, w, 9, 3)` float32, or `(T, 9, 3)` at the
    texels `at` (rows, columns) only."""
    features = _smooth_fill(features, source)[0]
    l0 = _hdr(features[..., 0:3], source, scales[0], denoiser)
    iz = _hdr(features[..., 3:6], source, scales[1], denoiser)
    l0_lum = l0 @ LUMINANCE
    ratios = _ratios(features[..., DIRECTIONAL], l0_lum)
    del features
    return _assemble(ratios, n, l0, iz, l0_lum, denoiser, at=at)


def _ratios(directional: np.ndarray, l0_lum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The directional filter's inputs (`_ratio`) from a page's (or band's) filled features
    DIRECTIONAL `(h, w, 8)` (band 1 across n_v, band 2) and its denoised luminance L0 `(h, w)`."""
    return _ratio(directional[..., 0:3], l0_lum, BAND1_BOUND), _ratio(directional[..., 3:8], l0_lum, BAND2_BOUND)


def _assemble(
    ratios: tuple[np.ndarray, np.ndarray],
    n: np.ndarray,
    l0: np.ndarray,
    iz: np.ndarray,
    l0_lum: np.ndarray,
    denoiser: Denoiser,
    core: slice | None = None,
    at: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The SH `(h, w, 9, 3)` float32 of a page (or band) from its `_ratios`, its denoised,
    energy-corrected L0 and I_z `(h, w, 3)` (`_hdr`) and luminance L0 `(h, w)`: band 1 across
    n_v and band 2 denoised in directional mode over the denoised luminance L0, scaled by each
    colour's L0. `core`: only these rows (a band's; the filter still sees every row); `n`: the
    unit n_v of the rows returned; `at` (rows, columns) (in `core`'s rows): only these texels,
    `(T, 9, 3)` (memory: no SH image), WRITE_CHUNK at a time. What follows the filter is per
    texel, so they have the bits the whole image gives them."""
    # the rest in luminance over luminance L0 (one direction for all colours, as HHD keeps), scaled by each colour's L0
    across = _directional(ratios[0], l0_lum, BAND1_BOUND, denoiser, core)
    band2 = _directional(ratios[1], l0_lum, BAND2_BOUND, denoiser, core)
    if core is not None:
        l0, iz, l0_lum = l0[core], iz[core], l0_lum[core]
    across -= n * np.einsum("hwa,hwa->hw", n, across)[..., None]
    images = (across, band2, n, l0, iz, l0_lum)
    if at is None:
        return _sh_of(*images)
    # per texel from here: the texels asked for only, WRITE_CHUNK at a time (memory)
    out = np.empty((len(at[0]), 9, 3), np.float32)
    for s in range(0, len(out), WRITE_CHUNK):
        part = (at[0][s : s + WRITE_CHUNK], at[1][s : s + WRITE_CHUNK])
        out[s : s + WRITE_CHUNK] = _sh_of(*(image[part] for image in images))
    return out


def _sh_of(
    across: np.ndarray, band2: np.ndarray, n: np.ndarray, l0: np.ndarray, iz: np.ndarray, l0_lum: np.ndarray
) -> np.ndarray:
    """`_assemble`'s SH `(..., 9, 3)` float32 from its parts `(..., c)` (per texel): the denoised
    band 1 across n_v (3 axes, luminance) and band 2 (5, luminance), unit n_v, L0 and I_z (RGB),
    luminance L0."""
    colour = l0 / np.where(l0_lum > 0.0, l0_lum, 1.0)[..., None]  # (..., 3): L0 of each colour / luminance L0
    scaled_iz = iz / IRRADZ_FROM_R10
    out = np.empty(l0.shape[:-1] + (9, 3), np.float32)
    out[..., 0, :] = l0
    # v = across ⊗ colour + n ⊗ I_z / IRRADZ_FROM_R10 (3 axes × 3 colours), one axis at a time (memory)
    for k, (axis, sign) in zip((1, 2, 3), ((1, -1.0), (2, 1.0), (0, -1.0))):
        v = across[..., axis, None] * colour + n[..., axis, None] * scaled_iz
        out[..., k, :] = -v if sign < 0 else v
    out[..., 4:, :] = band2[..., None] * colour[..., None, :]
    return out


def _hdr(colour: np.ndarray, source: np.ndarray, scale: float, denoiser: Denoiser) -> np.ndarray:
    """An HDR colour image `(h, w, 3)` denoised (inputScale `scale`), ≥ 0, then scaled per channel
    so its sum over the chart texels `source` is the input's (clamped to ×[1/ENERGY_CLAMP,
    ENERGY_CLAMP]): at a few samples per texel the noise is heavy-tailed and the filter takes the
    rare bright samples for outliers, darkening the page; the sum over a page of texels is an
    unbiased estimate with little noise of its own."""
    out = _hdr_filtered(colour, scale, denoiser)
    before = colour[source].sum(axis=0, dtype=np.float64)
    after = out[source].sum(axis=0, dtype=np.float64)
    return out * _energy_ratio(before, after)


def _hdr_filtered(colour: np.ndarray, scale: float, denoiser: Denoiser) -> np.ndarray:
    """`_hdr`'s filter, before its energy correction: the colour `(h, w, 3)` (≥ 0) raised to
    HDR_POWER, denoised (inputScale `scale`: `_compressed_scale`'s), ≥ 0, raised back. float32,
    finite (at most float32's largest value)."""
    out = np.maximum(denoiser.denoise(_compressed(colour).astype(np.float32), input_scale=scale), 0.0)
    back = np.power(out, 1.0 / HDR_POWER, dtype=np.float64)
    return np.minimum(back, np.finfo(np.float32).max).astype(np.float32)


def _compressed_scale(colour: np.ndarray) -> float:
    """The inputScale of `_hdr_filtered` for HDR colours `(T, 3)` ≥ 0 (a page's chart texels):
    OIDN's auto-exposure (`input_scale`) of the image it filters, the colours raised to HDR_POWER."""
    return input_scale(_compressed(colour))


def _compressed(colour: np.ndarray) -> np.ndarray:
    """HDR colours (any shape) ≥ 0 raised to HDR_POWER (negative values taken as 0), float64."""
    return np.power(np.maximum(colour, 0.0), HDR_POWER, dtype=np.float64)


def _energy_ratio(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """`_hdr`'s energy correction (3,) float32 from the traced and the filtered sums."""
    ratio = np.where(after > 0.0, before / np.where(after > 0.0, after, 1.0), 1.0)
    return np.clip(ratio, 1.0 / ENERGY_CLAMP, ENERGY_CLAMP).astype(np.float32)


def _band1_vector(sh: np.ndarray) -> np.ndarray:
    """v = (-r_1^1, -r_1^-1, r_1^0) of SH `(..., 9, C)` -> `(..., 3, C)`: I_z is IRRADZ_FROM_R10 · v·n_v."""
    return np.stack([-sh[..., 3, :], -sh[..., 1, :], sh[..., 2, :]], axis=-2)


def _ratio(coefficients: np.ndarray, l0: np.ndarray, bound: float) -> np.ndarray:
    """`_directional`'s input: luminance coefficients `(h, w, m)` divided by the denoised
    luminance L0 `(h, w)` and by `bound` (their largest |c / c_0| for radiance ≥ 0) times
    DIRECTIONAL_RANGE, clipped to [-1, 1]; 0 where L0 is. float32, FEATURE_ROWS rows at a time
    (per texel; memory)."""
    to_unit = DIRECTIONAL_RANGE / bound
    ratio = np.empty(coefficients.shape, np.float32)
    for y in range(0, len(ratio), FEATURE_ROWS):
        rows = slice(y, y + FEATURE_ROWS)
        lit = (l0[rows] > 0.0)[..., None]
        part = np.where(lit, coefficients[rows] / np.where(lit, l0[rows, :, None], 1.0) * to_unit, 0.0)
        ratio[rows] = np.clip(part, -1.0, 1.0)
        del part
    return ratio


def _directional(
    ratio: np.ndarray, l0: np.ndarray, bound: float, denoiser: Denoiser, core: slice | None = None
) -> np.ndarray:
    """Luminance coefficients, as their `_ratio` `(h, w, m)`, denoised in OIDN's directional
    mode, three at a time, and scaled back by L0 `(h, w)` and `bound`; `core`: only these rows
    are scaled back and returned."""
    to_unit = DIRECTIONAL_RANGE / bound
    clean = np.concatenate(
        [
            denoiser.denoise(ratio[..., k : k + 3], directional=True, input_scale=1.0)
            for k in range(0, ratio.shape[-1], 3)
        ],
        axis=-1,
    )
    if core is not None:
        clean, l0 = clean[core], l0[core]
    return clean / to_unit * l0[..., None]


#: One Denoiser per (library, threads) for the process: the device and weights load once.
_DENOISERS: dict[tuple[str, int], Denoiser] = {}


def denoiser_for(library: str | Path | None, threads: int) -> Denoiser:
    """The process's Denoiser for `library` (OIDN's shared library; None or "" = not found) on
    `threads` threads. Raises DenoiserUnavailable with the reason."""
    from .oidn import DenoiserUnavailable

    if not library:
        raise DenoiserUnavailable("Open Image Denoise library not found in this Blender")
    key = (str(library), int(threads))
    if key not in _DENOISERS:
        _DENOISERS[key] = Denoiser(library, threads=threads)
    return _DENOISERS[key]
