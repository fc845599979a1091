"""The blend of light sets the talk warns against, for comparison with `core.light_sets.blend`
(tests/test_light_sets_math.py, bench/light_sets.py). numpy, no bpy. Not shipped; moved here
unchanged from core/light_sets.py (issue 55: only tests and benches call it)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hhd_lightmapper.core.hhd import HHDParams


def parameter_blend(params: Sequence[HHDParams], weights: np.ndarray) -> HHDParams:
    """The wrong way the talk warns against, for comparison (benches, tests): I_z summed with
    the weights, w_a and d averaged with each set's weighted I_z luminance as weight."""
    weights = np.asarray(weights, dtype=np.float64)
    iz = sum(w[None, :] * p.irradz for p, w in zip(params, weights))
    share = np.stack([(w[None, :] * p.irradz).mean(axis=1) for p, w in zip(params, weights)])  # (K, N)
    share = share / np.maximum(share.sum(axis=0), 1e-300)
    wa = sum(
        s * (p.ambient_weight if p.ambient_weight.ndim == 1 else p.ambient_weight.mean(axis=1))
        for s, p in zip(share, params)
    )
    d = sum(s[:, None] * p.direction for s, p in zip(share, params))
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return HHDParams(irradz=iz, ambient_weight=np.clip(wa, 0.0, 1.0), direction=d, model="hhd")
