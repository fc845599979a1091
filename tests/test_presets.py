"""Presets: what the panel and the command line offer comes from the measured trade-off
(bench/tradeoff.py writes bench/results/presets.json; core/presets.py holds the same knobs)."""

import json
from pathlib import Path

import numpy as np
import pytest

from hhd_lightmapper.core import hhd, presets
from scenekit import synthetic

MEASURED = Path(__file__).resolve().parent.parent / "bench" / "results" / "presets.json"


def test_presets_are_the_measured_ones():
    measured = json.loads(MEASURED.read_text())
    assert list(measured) == list(presets.PRESETS)
    for name, m in measured.items():
        assert m["found"], f"{name}: the bench found no setting within {m['level']}%"
        assert presets.PRESETS[name].knobs() == (m["samples"], m["bounces"], m["noise_target"], m["denoise"]), name


def test_presets_get_more_accurate_in_order():
    measured = json.loads(MEASURED.read_text())
    worst = [max(s["iz_rmse"] for s in m["per_scene"].values()) for m in measured.values()]
    assert worst == sorted(worst, reverse=True)


def test_unknown_preset_names_the_valid_ones():
    with pytest.raises(ValueError, match="draft, preview, production, reference"):
        presets.get("ultra")


def test_golden_iterations_only_refine_the_direction():
    env = synthetic.interior()
    n_v = synthetic.random_normals(np.random.default_rng(3), 400)
    sh = synthetic.hemisphere_sh(env, n_v)
    errors = {}
    for steps in (0, 4, hhd.GOLDEN_ITERATIONS):
        p = hhd.encode(sh, n_v, golden_iterations=steps)
        errors[steps] = hhd.fit_error(sh, n_v, p.direction)[0]
    assert (errors[4] <= errors[0] * (1 + 1e-9) + 1e-15).all()
    assert (errors[hhd.GOLDEN_ITERATIONS] <= errors[4] * (1 + 1e-9) + 1e-15).all()
    assert errors[hhd.GOLDEN_ITERATIONS].sum() < errors[0].sum()
