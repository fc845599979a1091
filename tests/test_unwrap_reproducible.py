"""The unwrap is reproducible (issue 58): the same meshes and settings give byte-identical UVs
however long the packs take (no clock is read), whatever the session unwrapped before, and on
any number of cores. Real xatlas children throughout."""

import time

import numpy as np
import pytest

from hhd_lightmapper.core import unwrap
from hhd_lightmapper.core.unwrap import charting, packing
from scenekit import meshes

SETTINGS = unwrap.UnwrapSettings(resolution=256, padding=2)


@pytest.fixture(autouse=True)
def fresh_cache():
    unwrap.clear_chart_cache()
    yield
    unwrap.clear_chart_cache()


@pytest.fixture
def pieces(monkeypatch):
    """Charting splits meshes above 100 triangles into pieces, as it splits those above
    TRIANGLES_PER_PROCESS: the scene's "parts" mesh (5 connected parts) is charted in pieces."""
    monkeypatch.setattr(charting, "TRIANGLES_PER_PROCESS", 100)


def parts_mesh():
    """Five bumpy sheets, 72 triangles each, as one mesh: five connected parts."""
    parts = [meshes.bumpy_quads(n=6, amplitude=0.3, seed=k) for k in range(5)]
    v, f, poly = meshes.combine(*[(pv + [3.0 * k, 0, 0], pf, pp) for k, (pv, pf, pp) in enumerate(parts)])
    return unwrap.UnwrapMesh("parts", v, f, polygons=poly)


def scene():
    """Many charts: the parts mesh, a UV sphere and a warped n-gon."""
    sv, sf = meshes.uv_sphere(rings=8, segments=16)
    nv, nf, npoly = meshes.ngon(sides=9, bump=0.4)
    return [
        parts_mesh(),
        unwrap.UnwrapMesh("sphere", sv + [0.0, 4.0, 0.0], sf),
        unwrap.UnwrapMesh("ngon", nv + [4.0, 4.0, 0.0], nf, polygons=npoly),
    ]


def run(meshes_=None):
    """(UVs of every object, the densities the fit tried) of an unwrap of `meshes_` (the scene)."""
    res = unwrap.unwrap(meshes_ or scene(), SETTINGS)
    return [o.uv for o in res.objects], res.stats["tries"]


def assert_same(a, b):
    (uv_a, tries_a), (uv_b, tries_b) = a, b
    assert tries_a == tries_b
    assert [u.tobytes() for u in uv_a] == [u.tobytes() for u in uv_b]


def refined(tries) -> bool:
    """Whether the fit packed a round after the first round that fitted."""
    fits = [f for _, f in tries[0]]
    return True in fits and len(fits) - fits.index(True) > 2


def test_slow_packs_give_the_same_atlas(monkeypatch):
    """Every pack round seeming to take 100 s (a very busy machine: each clock jumps by 100 s
    after each round) changes neither the densities tried nor a byte of the UVs."""
    monkeypatch.setattr(packing, "_cores", lambda: 2)
    monkeypatch.setattr(packing, "ONE_CHILD_TRIANGLES", 0)  # the fit is driven from this process
    quiet = run()
    assert refined(quiet[1])
    unwrap.clear_chart_cache()
    elapsed = [0.0]
    for name in ("perf_counter", "monotonic", "time", "process_time"):
        clock = getattr(time, name)
        monkeypatch.setattr(time, name, lambda clock=clock: clock() + elapsed[0])
    pack_at = packing._pack_at

    def slow_pack_at(*args, **kwargs):
        out = pack_at(*args, **kwargs)
        elapsed[0] += 100.0
        return out

    monkeypatch.setattr(packing, "_pack_at", slow_pack_at)
    busy = run()
    assert_same(busy, quiet)
    assert elapsed[0] == 100.0 * len(busy[1][0]) / 2  # two densities a round


def test_an_unwrap_gives_the_same_uvs_again_whatever_the_session_unwrapped_before(monkeypatch, pieces):
    """Unwrapped twice from an empty cache, and after the parts mesh was unwrapped alone (its
    charts then come from the cache, charted without the other meshes): the same bytes."""
    monkeypatch.setattr(charting, "_cores", lambda: 2)
    first = run()
    unwrap.clear_chart_cache()
    assert_same(run(), first)
    unwrap.clear_chart_cache()
    run([parts_mesh()])
    again = unwrap.unwrap(scene(), SETTINGS)
    assert again.stats["cached"] == 1
    assert_same(([o.uv for o in again.objects], again.stats["tries"]), first)


def test_the_atlas_does_not_depend_on_the_core_count(monkeypatch, pieces):
    """One, two or four cores (charting children, and the fit in one child or driven from here
    with two children at once): the same densities tried and the same bytes of UVs."""
    monkeypatch.setattr(packing, "ONE_CHILD_TRIANGLES", 0)
    runs = []
    for cores in (1, 2, 4):
        for module in (charting, packing):
            monkeypatch.setattr(module, "_cores", lambda cores=cores: cores)
        unwrap.clear_chart_cache()
        runs.append(run())
    assert refined(runs[0][1])
    for other in runs[1:]:
        assert_same(other, runs[0])
    assert np.unique(charting._CACHE[charting.chart_key(parts_mesh())].chart).size > 5  # many charts
