"""The stitching's compiled products (`core/post/seams/solve_kernels.py`) give the bits of the
numpy expressions they replaced (kept here as the reference): A x and Aᵀ r in float32 and
float64, with runs of every length (numpy's pairwise summation blocks and the runs past them,
which numpy sums itself), signed zeros, infinities and NaN. And a stitch of a real atlas is the
same whichever computes them. No Blender."""

import numpy as np
import pytest

from hhd_lightmapper.core.post.seams import solve
from hhd_lightmapper.core.post.seams.solve_kernels import PAIRWISE_BLOCK


def reference_apply_a(s, x):
    out = np.zeros((x.shape[0], s.taps.shape[1]), x.dtype)
    for k in range(len(s.taps)):
        out += np.take(x, s.taps[k], axis=1) * s.coeff[k]
    return out


def reference_apply_at(s, r):
    out = np.zeros((r.shape[0], len(s.texels)), r.dtype)
    if len(s.starts):
        out[:, s.owner] = np.add.reduceat(np.take(r, s.entry_row, axis=1) * s.entry_coeff, s.starts, axis=1)
    return out


def system(rows=3000, unknowns=900, seed=0):
    """A `solve._System` of `rows` rows of 8 taps (some fixed: coefficient 0 on tap 0), whose
    unknowns are read by 1 … ~300 entries each (runs shorter than 8, within the pairwise block,
    and past it)."""
    rng = np.random.default_rng(seed)
    weights = rng.pareto(1.2, unknowns) + 0.05  # a heavy tail: a few unknowns take hundreds of entries
    taps = rng.choice(unknowns, size=(8, rows), p=weights / weights.sum())
    coeff = rng.normal(size=(8, rows)).astype(np.float32)
    coeff[0, ::7] = 0.0
    flat = taps.reshape(-1)
    order = np.argsort(flat, kind="stable")
    order = order[coeff.reshape(-1)[order] != 0.0]
    sorted_taps = flat[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_taps[1:] != sorted_taps[:-1]]))
    return solve._System(
        texels=np.arange(unknowns),
        taps=taps,
        coeff=coeff,
        seam_weight=np.ones(rows),
        constant=np.zeros((1, rows)),
        data_weight=np.ones(unknowns),
        entry_row=order % rows,
        entry_coeff=coeff.reshape(-1)[order].astype(np.float32),
        starts=starts,
        owner=sorted_taps[starts],
        dropped=0,
    )


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_compiled_products_are_numpys_bits(dtype):
    s = system()
    runs = np.diff(np.concatenate([s.starts, [len(s.entry_row)]]))
    assert runs.min() == 1 and ((runs > 1) & (runs < 9)).any() and ((runs > 9) & (runs <= PAIRWISE_BLOCK)).any()
    assert (runs > PAIRWISE_BLOCK + 1).any()  # left to numpy
    rng = np.random.default_rng(1)
    x = (rng.normal(size=(5, len(s.texels))) * 10.0 ** rng.integers(-6, 6, size=(5, len(s.texels)))).astype(dtype)
    x[0, :40] = -0.0
    x[1, 3] = np.inf
    x[2, 5] = np.nan
    assert solve._apply_a(s, x).tobytes() == reference_apply_a(s, x).tobytes()
    r = (rng.normal(size=(5, s.taps.shape[1])) * 10.0 ** rng.integers(-6, 6, size=(5, s.taps.shape[1]))).astype(dtype)
    r[0, :300] = -0.0
    r[3, 7] = -np.inf
    r[4, 11] = np.nan
    with np.errstate(invalid="ignore"):  # inf − inf in a sum
        got, expected = solve._apply_at(s, r), reference_apply_at(s, r)
    assert got.dtype == expected.dtype == dtype
    assert got.tobytes() == expected.tobytes()
