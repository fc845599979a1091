"""The noise clamp: no denoised coefficient further than NOISE_CLAMP standard errors from the
traced value (`clamp_to_noise`), the bound narrower on small charts and wider at a chart's edge
(`_ChartNoise`, `chart_edge`); the denoised texels written through it (`_write`). No bpy."""

from __future__ import annotations

import numpy as np

from ...colour import LUMINANCE

#: Most standard errors (of the traced value, `TexelData.noise`) the denoiser may move a coefficient.
NOISE_CLAMP = 2.5
#: Baked texels of a chart below which its NOISE_CLAMP bound shrinks (`_ChartNoise`).
SMALL_CHART = 256
#: The NOISE_CLAMP bound of a texel within EDGE_RINGS (chessboard distance) of a texel that is
#: not of its chart is EDGE_CLAMP times as wide (`_ChartNoise`).
EDGE_RINGS, EDGE_CLAMP = 2, 0.6
#: Texels clamped to the noise and written (`_write`), or assembled (`_assemble`), at once.
WRITE_CHUNK = 1 << 16
#: Rows of the atlas per step of the atlas-wide passes (`clamp_to_noise`, `_finite_texels`): bounds their temporaries.
ROWS_PER_STEP = 64


class _ChartNoise:
    """The standard errors the noise clamp scales, read per texel: the traced `noise` (H·W,)
    float32 times min(1, √(baked texels of the texel's chart / SMALL_CHART)), and times
    EDGE_CLAMP within EDGE_RINGS of the chart's edge (`labels` (H, W) chart labels 0..n-1, -1
    elsewhere, where both factors are 1). Indexing gathers only the texels asked for: no
    atlas-wide copy of the noise (memory: one byte an atlas texel for the edge)."""

    def __init__(self, noise: np.ndarray, labels: np.ndarray, n: int):
        self.noise, self.flat = noise, labels.reshape(-1)
        size = np.bincount(self.flat[self.flat >= 0], minlength=n)
        self.factor = np.minimum(1.0, np.sqrt(size / SMALL_CHART)).astype(np.float32)
        self.edge = chart_edge(labels, EDGE_RINGS).reshape(-1)

    def __getitem__(self, index) -> np.ndarray:
        label = self.flat[index]
        chart = np.where(label >= 0, self.factor[np.maximum(label, 0)], np.float32(1.0))
        edge = np.where(self.edge[index] & (label >= 0), np.float32(EDGE_CLAMP), np.float32(1.0))
        return self.noise[index] * chart * edge


def chart_edge(labels: np.ndarray, rings: int) -> np.ndarray:
    """`(H, W)` bool: the texels with a texel of another label (or outside the atlas) within
    `rings` texels (chessboard distance) of them, from `labels` `(H, W)`. A texel's whole
    (2·rings + 1)² window has its label iff every row of the window does: each row's run of
    2·rings + 1 texels is checked once (`same_row`), then `rings` rows up and down;
    ROWS_PER_STEP rows at a time (memory)."""
    h, w = labels.shape
    edge = np.empty((h, w), bool)
    for y0 in range(0, h, ROWS_PER_STEP):
        y1 = min(y0 + ROWS_PER_STEP, h)
        lo, hi = max(y0 - rings, 0), min(y1 + rings, h)
        block = labels[lo:hi]
        padded = np.pad(block, ((0, 0), (rings, rings)), constant_values=-2)
        same_row = np.ones(block.shape, bool)  # the row's run around each texel has its label
        for dx in range(-rings, rings + 1):
            if dx:
                same_row &= padded[:, rings + dx : rings + dx + w] == block
        inner = np.ones((y1 - y0, w), bool)
        centre = labels[y0:y1]
        for dy in range(-rings, rings + 1):
            ys = np.arange(y0, y1) + dy
            inside = (ys >= 0) & (ys < h)
            rows = np.clip(ys, 0, h - 1) - lo
            inner &= inside[:, None] & same_row[rows] & (block[rows] == centre)
        edge[y0:y1] = ~inner
    return edge


def _write(
    out: np.ndarray,
    index: np.ndarray,
    clean: np.ndarray,
    traced: np.ndarray | None,
    noise: _ChartNoise | None,
    gather: bool = False,
) -> None:
    """Denoised SH `clean` `(T, 9, 3)` of the texels `index` into `out`, clamped to the noise
    around their `traced` SH where `noise` (`_ChartNoise`) is given (`clamp_to_noise`'s bits, per texel;
    `traced` is then required), WRITE_CHUNK texels at a time (the clamp's temporaries: memory).
    `gather`: `traced` is the `(H·W, 9, 3)` SH to read them at `index` from (it may be `out`:
    each chunk is read before it is written)."""
    if noise is None:
        out[index] = clean
        return
    assert traced is not None
    for s in range(0, len(index), WRITE_CHUNK):
        part = index[s : s + WRITE_CHUNK]
        before = traced[part] if gather else traced[s : s + WRITE_CHUNK]
        out[part] = _clamp_rows(clean[None, s : s + WRITE_CHUNK], before[None], noise[part][None])[0]


def _clamp_unwritten(sh: np.ndarray, noise: np.ndarray, written: np.ndarray) -> None:
    """`clamp_to_noise` of the texels of `sh` `(H, W, 9, 3)` no page wrote (`written` (H·W,)
    False; denoised = traced: traced + 0, which only turns -0 into +0), in place, ROWS_PER_STEP
    rows at a time. Only texels of known noise are touched: the clamp leaves the others as
    they are (most unwritten texels lie outside the charts, where the noise is unknown)."""
    written = written.reshape(sh.shape[:2])
    for y in range(0, sh.shape[0], ROWS_PER_STEP):
        rows = slice(y, y + ROWS_PER_STEP)
        keep = ~written[rows] & np.isfinite(noise[rows])
        if not keep.any():
            continue
        block = sh[rows][keep]
        sh[rows][keep] = _clamp_rows(block[None], block[None], noise[rows][keep][None])[0]


def clamp_to_noise(
    denoised: np.ndarray, traced: np.ndarray, noise: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """`denoised` SH `(H, W, 9, 3)` moved back to within NOISE_CLAMP standard errors of the
    `traced` SH, per coefficient and colour: the bound is NOISE_CLAMP × `noise` `(H, W)` (the
    standard error of the traced luminance L0) × each colour's share of that luminance (|L0_c| /
    L0 luminance; 1 where it is not positive). Texels whose noise is unknown (NaN) are not
    clamped; non-finite traced values are not either (the filter replaced them). float32, into
    `out` if given (it may be `denoised` itself), ROWS_PER_STEP rows at a time (memory)."""
    if out is None:
        out = np.empty(denoised.shape, np.float32)
    for y in range(0, denoised.shape[0], ROWS_PER_STEP):
        rows = slice(y, y + ROWS_PER_STEP)
        out[rows] = _clamp_rows(denoised[rows], traced[rows], noise[rows])
    return out


def _clamp_rows(denoised: np.ndarray, traced: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """`clamp_to_noise` of some rows."""
    l0 = traced[..., 0, :].astype(np.float64)
    l0_lum = l0 @ LUMINANCE
    lit = l0_lum > 0.0
    colour = np.where(lit[..., None], np.abs(l0) / np.where(lit, l0_lum, 1.0)[..., None], 1.0)
    known = np.isfinite(noise) & np.isfinite(traced).all(axis=(2, 3))
    if not known.any():  # nothing to clamp (e.g. fewer than NOISE_PASSES passes)
        return denoised.astype(np.float32, copy=False)
    bound = NOISE_CLAMP * np.where(known, noise, 0.0)[..., None] * colour  # (H, W, 3)
    step = np.clip(denoised - traced, -bound[:, :, None, :], bound[:, :, None, :])
    return np.where(known[..., None, None], traced + step, denoised).astype(np.float32)
