"""Progress and cancellation in the stages after the trace (core/progress.py, core/bake/; no
Blender): seams, denoise, stitch, encode and the EXR writes each report within their share of
the bake's range, with their name; the fraction never goes back and is 1.0 only at the end; a
cancel raised while they run leaves the previous files as they were."""

import hashlib
import json
import re

import numpy as np
import pytest

from hhd_lightmapper.core import bake, bakepoints, progress, unwrap
from hhd_lightmapper.core.errors import BakeCancelled
from hhd_lightmapper.core.post.denoise import pages as denoise
from hhd_lightmapper.core.scene import BakeScene, SunLight
from hhd_lightmapper.core.tracer import BakeSettings
from scenekit import meshes
from test_oidn import bpy_library_dirs, denoiser, library  # noqa: F401  (fixtures)

RES = 256
TRACE = BakeSettings(samples=4, pass_samples=4, bounces=1, seed=5, chunk_texels=2048)


def floor_and_ball():
    """A floor and a smooth ball on it, one atlas: several charts and smooth seams to stitch."""
    fv, ff = meshes.plane(2.0)
    sv, sf = meshes.uv_sphere(8, 16)
    parts = [(fv, ff, np.tile([0, 0, 1.0], (len(fv), 1))), (0.5 * sv + [0.2, 0.1, 0.5], sf, sv)]
    res = unwrap.unwrap(
        [unwrap.UnwrapMesh(f"m{k}", v, f) for k, (v, f, _) in enumerate(parts)],
        unwrap.UnwrapSettings(resolution=RES, padding=4),
    )
    tris = np.concatenate([v[f] for v, f, _ in parts])
    normals = np.concatenate([(n / np.linalg.norm(n, axis=1, keepdims=True))[f] for _, f, n in parts])
    uv = np.concatenate([o.uv for o in res.objects]).astype(float)
    objects = np.concatenate([np.full(len(f), k) for k, (_, f, _) in enumerate(parts)])
    surface = bakepoints.SurfaceTriangles(tris, normals, uv, objects, np.full((len(tris), 3), 0.5))
    scene = BakeScene(
        tris,
        np.full((len(tris), 3), 0.5),
        lights=[SunLight(np.array([0.5, 0.3, 0.8]), np.full(3, 3.0))],
        world=np.array([0.1, 0.2, 0.3]),
    )
    return bake.AtlasInput("Lightmap", RES, RES, surface, ["floor", "ball"]), scene


def folder_hash(folder) -> dict:
    """Every file under `folder` (by relative path): its SHA-256."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def without_timings(doc):
    """A sidecar without what differs between two runs of one bake (seconds, speeds)."""
    if isinstance(doc, dict):
        return {k: without_timings(v) for k, v in doc.items() if "second" not in k and "timing" not in k}
    if isinstance(doc, list):
        return [without_timings(v) for v in doc]
    return doc


@pytest.fixture(scope="module")
def settings(library, denoiser):  # noqa: F811
    return bake.PipelineSettings(trace=TRACE, denoise=True, denoiser_library=str(library), stitch_seams=True)


@pytest.fixture(scope="module")
def baked(tmp_path_factory, settings):
    """A denoised, stitched bake with every progress call recorded (and the files it wrote)."""
    atlas, scene = floor_and_ball()
    out = tmp_path_factory.mktemp("baked")
    calls = []
    bake.run([atlas], scene, settings, out, progress=lambda f, m: calls.append((f, m)))
    return calls, out


def after_trace(calls):
    last_trace = max(i for i, (_, m) in enumerate(calls) if "pass" in m or "chunk" in m)
    return calls[last_trace + 1 :]


def test_every_stage_after_the_trace_reports_with_its_name_and_the_bar_only_moves_forward(baked):
    calls, _ = baked
    fractions = [f for f, _ in calls]
    assert all(b >= a for a, b in zip(fractions, fractions[1:]))  # never back
    assert fractions[-1] == 1.0 and all(f <= progress.LAST for f in fractions[:-1])  # 100% only at the end
    later = after_trace(calls)
    assert len({f for f, _ in later}) >= 20  # the bar moves in many steps after the trace
    messages = [m for _, m in later]
    for stage in ("seams 'Lightmap'", "denoise 'Lightmap'", "stitch 'Lightmap'", "encode 'Lightmap'"):
        assert any(m.startswith(stage) for m in messages), stage
    assert any("denoise 'Lightmap': page 1 of" in m for m in messages)
    assert any("stitch 'Lightmap':" in m and "iteration" in m for m in messages)
    assert any(m.startswith("write 'Lightmap'") and "Lightmap_hhd.exr: rows" in m for m in messages)
    assert any(m.startswith("raw 'Lightmap'") and "rows" in m for m in messages)
    assert any("preview" in m for m in messages)
    assert "ETA" in messages[-2]
    # the stages after the trace take a share of the range in proportion to their estimated costs
    assert later[0][0] < 0.9


def test_progress_does_not_change_the_files(baked, settings, tmp_path):
    _, out = baked
    atlas, scene = floor_and_ball()
    bake.run([atlas], scene, settings, tmp_path)  # no progress callback
    files, expected = folder_hash(tmp_path), folder_hash(out)
    assert sorted(files) == sorted(expected) and len(files) >= 8  # sidecar, seams, 3 EXRs, the HHD file's 3 previews
    assert {k: v for k, v in files.items() if not k.endswith(".json")} == {
        k: v for k, v in expected.items() if not k.endswith(".json")
    }
    sidecar = [without_timings(json.loads((folder / "Lightmap.json").read_text())) for folder in (tmp_path, out)]
    assert sidecar[0] == sidecar[1]


@pytest.mark.parametrize(
    "where",
    ["denoise 'Lightmap'", "stitch 'Lightmap'", "encode 'Lightmap'", "raw 'Lightmap'", "write 'Lightmap'"],
)
def test_a_cancel_during_a_stage_after_the_trace_leaves_the_previous_files(baked, settings, tmp_path, where):
    _, out = baked
    atlas, scene = floor_and_ball()
    previous = tmp_path / "out"
    previous.mkdir()
    for name in folder_hash(out):  # a previous bake in the folder
        (previous / name).parent.mkdir(parents=True, exist_ok=True)
        (previous / name).write_bytes((out / name).read_bytes())
    (previous / "notes.txt").write_text("mine")
    before = folder_hash(previous)
    seen = []

    def on_progress(fraction, message):
        seen.append(message)
        if message.startswith(where) and len([m for m in seen if m.startswith(where)]) == 2:
            raise BakeCancelled("cancelled from the progress callback")

    with pytest.raises(BakeCancelled):
        bake.run([atlas], scene, settings, previous, progress=on_progress)
    assert folder_hash(previous) == before
    assert sorted(str(p.relative_to(previous)) for p in previous.rglob("*") if p.is_file()) == sorted(before)


def test_esc_is_honoured_inside_the_denoiser_band_by_band(settings, tmp_path, monkeypatch):
    """The cancel flag (Esc, Ctrl-C) is checked at each denoiser band: set while a page is
    denoised in bands, the bake stops before the next band."""
    monkeypatch.setattr(denoise, "BAND_TEXELS", 16 * RES)  # bands of 16 rows: several per page
    monkeypatch.setattr(denoise, "BAND_OVERLAP", 16)
    atlas, scene = floor_and_ball()
    flag, bands = [], []

    def on_progress(fraction, message):
        if message.startswith("denoise 'Lightmap'") and "band" in message:
            bands.append(message)
            flag.append(True)

    with pytest.raises(BakeCancelled):
        bake.run([atlas], scene, settings, tmp_path, progress=on_progress, cancel=lambda: bool(flag))
    assert len(bands) == 1 and "page 1 of" in bands[0]
    assert not folder_hash(tmp_path)  # no file written (Staging leaves only the empty preview folder)


def test_shares_follow_the_remaining_work_and_never_go_back():
    seen = []
    report = progress.Progress(lambda f, m: seen.append(f))
    report.plan(100.0)
    a = report.span(25.0, "a")
    a.at(1.0)
    assert seen[-1] == pytest.approx(0.25)
    b = report.span(25.0, "b")
    b.at(0.5)  # stops early: what is left is shared again from where the bar is
    c = report.span(50.0, "c")
    assert (c.lo, c.hi) == (pytest.approx(0.375), pytest.approx(1.0))
    first, second = c.split([1.0, 3.0])
    second.at(0.0)
    first.at(1.0)  # an earlier part reporting late does not move the bar back
    c.at(1.0)
    assert seen == sorted(seen) and seen[-1] == progress.LAST
    report.finish("done")
    assert seen[-1] == 1.0


def test_an_unwrap_reports_its_eta_as_a_bake_does(monkeypatch):
    """`progress.with_eta`: the fractions pass through unchanged; past 2% the message ends with
    the ETA from the time since the first report (here 10 s for the first quarter: 30 s left);
    none before 2% nor at 100%."""
    clock = iter([100.0, 100.0, 110.0, 130.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    calls = []
    report = progress.with_eta(lambda f, m: calls.append((f, m)))
    for f, m in ((0.01, "xatlas: charting"), (0.25, "xatlas: charted 1 of 4 parts"), (1.0, "xatlas: done")):
        report(f, m)
    assert calls == [
        (0.01, "xatlas: charting"),
        (0.25, "xatlas: charted 1 of 4 parts, ETA 30 s"),
        (1.0, "xatlas: done"),
    ]


def test_the_stages_before_the_trace_report_their_parts_in_order(baked):
    """The inward check and the bake points (rasterising, the cover probe, settling, buried and
    near-cover texels) each report within their share, before the trace's first chunk."""
    calls, _ = baked
    first_trace = min(i for i, (_, m) in enumerate(calls) if "chunk" in m or "pass" in m)
    before = [m for _, m in calls[:first_trace]]
    parts = [
        "faces that point in",
        "bake points of 'Lightmap': rasterising",
        "bake points of 'Lightmap': cover probe",
        "bake points of 'Lightmap': settling",
        "bake points of 'Lightmap': buried texels",
        "bake points of 'Lightmap': near cover",
    ]
    where = [next(i for i, m in enumerate(before) if m.startswith(p)) for p in parts]
    assert where == sorted(where)
    assert re.fullmatch(r"bake points of 'Lightmap': \d+ texels, ETA .*", before[-1])
    assert sum(m.startswith("bake points of 'Lightmap': settling") for m in before) >= 2  # per chunk


@pytest.mark.parametrize("where", ["faces that point in", "bake points of 'Lightmap': settling"])
def test_a_cancel_before_the_trace_stops_the_bake_and_writes_nothing(settings, tmp_path, where):
    atlas, scene = floor_and_ball()
    seen = []

    def on_progress(fraction, message):
        seen.append(message)
        if message.startswith(where):
            raise BakeCancelled("cancelled from the progress callback")

    with pytest.raises(BakeCancelled):
        bake.run([atlas], scene, settings, tmp_path, progress=on_progress)
    assert not any("chunk" in m for m in seen)
    assert not folder_hash(tmp_path)
