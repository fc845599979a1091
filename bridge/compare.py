"""Compare every encoding of a finished bake against Cycles from the scene camera (the bpy half of
`core.compare`; `bpy.ops.hhd.compare()`, the CLI's `compare`).

The reference renders: Cycles on the CPU from the scene camera, sample clamps off, no denoising,
the bake's bounce count (Cycles counts from the camera's hit, which plays the baked point), the pixel filter off (a ray through each pixel's centre, as the
comparison reads its pixels). Every material is changed for the render only, for camera rays
only (a Light Path node's Is Camera Ray picks): they see a white Lambertian surface (the diffuse
reference: radiance = I, docs/conventions.md) or a white GGX Glossy BSDF of each roughness (the
specular reference, F0 = 1), all other rays the material as it is, so the scene is lit as the
bake saw it; normal maps are off on both sides. Every material is restored afterwards, also
after an error. Receivers without a material are left out (named in the report).

Writes into `folder`: compare.md (the table), compare.json and contact_sheet.png (rows: the
reference, then each encoding; columns: diffuse, then specular per roughness; each column one
exposure, the reference's mean at mid-grey; black: pixels not compared or a term the encoding
does not model).

In steps (`Comparison`, so that the work shows progress and can be cancelled): `prepare` checks
everything and finds the compared pixels (no render, nothing changed); then one step per Cycles
render (two seeds of the diffuse pass, then of each roughness), one per atlas for its post stages
(reading its files, denoise, stitch), one per atlas and encoding, and the report last. `begin`
and `advance` run them one at a time with a progress report (the operator's modal path, one per
timer event); `run_steps` runs them all (`run`: the CLI, the operator's execute). The scene is
changed only inside a render step and put back at its end, also when the render fails
(`reference_setup`): between steps, after a cancel or an error it is as it was. The report's
files are staged and replace the old ones together in the last step only (`exr.Staging`): a
cancelled or failed comparison leaves an earlier report as it was.
"""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import bpy
import numpy as np

from .. import blender_compat
from ..core import compare as core_compare
from ..core import progress as core_progress
from ..core.colour import LUMINANCE
from ..core.console import ConsoleProgress
from ..core.encoding.web_packing import png_encode
from ..core.errors import BakeCancelled, BakeError
from ..core.files import exr, lightmap_files
from . import bake_session, denoiser, mesh_data, scene_data
from . import settings as bake_settings

ROUGHNESS = (0.25, 0.5, 0.75)
NODE_PREFIX = "HHD Compare"
GLOSSY, PICK = "Glossy", "Diffuse or Glossy"

# The steps' estimated costs, in microseconds on the 2-core test machine (only their ratios
# matter: each step's share of the progress bar; `core.progress` has the bake's), from this
# machine's comparisons (bench/compare.py's scenes, a floor and a cube). A Cycles render: per
# pixel and sample, × (1 + bounces), and its start (scene sync, shaders). An atlas's post stages
# and encodings: `core.progress`'s per texel, and for the SG encodings per lobe (their fit).
COST_RENDER_SAMPLE = 1.5
COST_RENDER_START = 5e4
COST_SG_LOBE = 2.0
#: Writing the report: per contact sheet pixel.
COST_REPORT_PIXEL = 0.5


def camera_of(scene, percentage: int = 100) -> core_compare.Camera:
    """The scene camera as a `core.compare.Camera` at `percentage` of the render size. Raises
    BakeError without a camera, or for lens shift / a panoramic camera (not modelled)."""
    cam = scene.camera
    if cam is None or cam.type != 'CAMERA':
        raise BakeError("the scene has no camera: the comparison renders from the scene camera")
    data = cam.data
    if data.type not in ('PERSP', 'ORTHO') or data.shift_x or data.shift_y:
        raise BakeError(
            f"camera '{cam.name}': only perspective or orthographic cameras without lens shift are compared"
        )
    width = max(8, scene.render.resolution_x * percentage // 100)
    height = max(8, scene.render.resolution_y * percentage // 100)
    aspect = width * scene.render.pixel_aspect_x / (height * scene.render.pixel_aspect_y)
    fit = data.sensor_fit if data.sensor_fit != 'AUTO' else ('HORIZONTAL' if aspect >= 1.0 else 'VERTICAL')
    half = 0.5 * data.ortho_scale if data.type == 'ORTHO' else math.tan(0.5 * data.angle)
    hx, hy = (half, half / aspect) if fit == 'HORIZONTAL' else (half * aspect, half)
    m = np.array(cam.matrix_world, np.float64)
    rotation = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    return core_compare.Camera(m[:3, 3].copy(), rotation, width, height, data.type, (hx, hy))


@contextlib.contextmanager
def reference_setup(scene, camera, samples: int, bounces: int):
    """Inside the block the scene renders a reference (module doc): every material's camera-ray
    switch added, Cycles set up (`_cycles`) for `samples` samples; after it, also after an
    error, every material and render setting is as it was (`_render_state`)."""
    saved = _render_state(scene)
    added = []
    try:
        for mat in bpy.data.materials:
            added += _camera_surface(mat)
        _cycles(scene, camera, samples, bounces)
        yield
    finally:
        for tree, nodes, link in added:
            for node in nodes:
                tree.nodes.remove(node)
            if link is not None:
                tree.links.new(*link)
        _restore_render_state(scene, saved)


def _camera_surface(mat) -> list:
    """Insert the camera-ray switch into `mat` (module doc); returns what to undo."""
    tree = blender_compat.node_tree_of(mat) if mat.library is None else None
    if tree is None:
        return []
    outputs = [n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL' and n.is_active_output]
    if not outputs:
        return []
    output = outputs[0]
    socket = output.inputs["Surface"]
    link = (socket.links[0].from_socket, socket) if socket.is_linked else None
    path = tree.nodes.new("ShaderNodeLightPath")
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    glossy = tree.nodes.new("ShaderNodeBsdfGlossy")
    pick = tree.nodes.new("ShaderNodeMixShader")  # diffuse (0) or glossy (1): driven by the pass
    mix = tree.nodes.new("ShaderNodeMixShader")
    nodes = [path, diffuse, glossy, pick, mix]
    for node, role in zip(nodes, ("Light Path", "Diffuse", GLOSSY, PICK, "Camera Rays")):
        node.name = node.label = f"{NODE_PREFIX} {role}"  # by role: Blender renames some node types
    diffuse.inputs["Color"].default_value = glossy.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    diffuse.inputs["Roughness"].default_value = 0.0
    if hasattr(glossy, "distribution"):
        glossy.distribution = 'GGX'
    tree.links.new(diffuse.outputs[0], pick.inputs[1])
    tree.links.new(glossy.outputs[0], pick.inputs[2])
    if link is not None:
        tree.links.new(link[0], mix.inputs[1])
    tree.links.new(pick.outputs[0], mix.inputs[2])
    tree.links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    tree.links.new(mix.outputs[0], socket)
    return [(tree, nodes, link)]


def _set_pass(roughness: float, glossy: bool) -> None:
    for mat in bpy.data.materials:
        tree = blender_compat.node_tree_of(mat)
        for node in tree.nodes if tree is not None else ():
            if node.name == f"{NODE_PREFIX} {PICK}":
                node.inputs["Fac"].default_value = 1.0 if glossy else 0.0
            if node.name == f"{NODE_PREFIX} {GLOSSY}":
                node.inputs["Roughness"].default_value = roughness


def _render(scene, path: Path, roughness: float, glossy: bool, seed: int) -> np.ndarray:
    """One reference render (inside `reference_setup`) as (H, W, 3), rows top first. Raises
    RuntimeError (Blender's) when the render fails, BakeError when it wrote no image."""
    _set_pass(roughness, glossy)
    scene.cycles.seed = seed
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if not path.is_file():
        raise BakeError(f"Cycles wrote no image to {path}")
    channels, _ = exr.read(path)
    return np.stack([channels[c] for c in "RGB"], -1).astype(np.float64)  # EXR rows: top first


_STATE = (
    ("render", ("engine", "filepath", "resolution_x", "resolution_y", "resolution_percentage")),
    ("cycles", ("device", "samples", "use_denoising", "max_bounces", "diffuse_bounces", "glossy_bounces")),
    ("cycles", ("transmission_bounces", "sample_clamp_direct", "sample_clamp_indirect", "use_adaptive_sampling")),
    ("cycles", ("seed", "pixel_filter_type", "filter_width")),
    ("image_settings", ("file_format", "color_mode", "color_depth")),
    ("view_settings", ("view_transform", "look", "exposure", "gamma")),
)


def _owner(scene, name):
    return {
        "render": scene.render,
        "cycles": scene.cycles,
        "image_settings": scene.render.image_settings,
        "view_settings": scene.view_settings,
    }[name]


def _render_state(scene) -> list:
    return [(owner, key, getattr(_owner(scene, owner), key)) for owner, keys in _STATE for key in keys]


def _restore_render_state(scene, saved) -> None:
    for owner, key, value in saved:
        setattr(_owner(scene, owner), key, value)


def _cycles(scene, camera, samples: int, bounces: int) -> None:
    r = scene.render
    r.engine = 'CYCLES'
    r.resolution_x, r.resolution_y, r.resolution_percentage = camera.width, camera.height, 100
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', samples, False, False
    # the pixel's centre, as the compared pixels' camera rays (Cycles reads its own filter, not filter_size)
    c.pixel_filter_type, c.filter_width = 'BOX', 0.01
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = bounces  # the camera's hit is the baked point
    c.transmission_bounces = 0
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    s = r.image_settings
    s.file_format, s.color_mode, s.color_depth = 'OPEN_EXR', 'RGB', '32'
    v = scene.view_settings
    v.view_transform, v.look, v.exposure, v.gamma = 'Standard', 'None', 0.0, 1.0


def run(
    context,
    objects: list[str] | None = None,
    out_dir: str | None = None,
    folder: str | None = None,
    *,
    samples: int = 256,
    roughness=ROUGHNESS,
    models=core_compare.MODELS,
    percentage: int = 50,
    progress: Callable[[float, str], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> tuple[str, list[str]]:
    """Compare every encoding of the receivers' atlases (the last bake in `out_dir`, default the
    output folder) against Cycles from the scene camera; writes the report into `folder`
    (default `<out_dir>/compare`). Returns (summary line, warnings). `progress(fraction,
    message)` hears of every step (default: a console line each); `cancel()` True stops at the
    next step (BakeCancelled; nothing changed)."""
    job = prepare(
        context, objects, out_dir, folder, samples=samples, roughness=roughness, models=models, percentage=percentage
    )
    console = ConsoleProgress(step=0.0) if progress is None else None
    try:
        return run_steps(job, progress or console, cancel)
    finally:
        if console is not None:
            console.close()


def prepare(
    context,
    objects: list[str] | None = None,
    out_dir: str | None = None,
    folder: str | None = None,
    *,
    samples: int = 256,
    roughness=ROUGHNESS,
    models=core_compare.MODELS,
    percentage: int = 50,
    settings=None,
) -> Comparison:
    """The comparison `run` makes, checked (a bake of every atlas, a receiver seen by the camera:
    BakeError otherwise) and its compared pixels found, before any render; nothing is changed.
    `settings`: the scene's HHD settings (None) or an `Overridden` view of them (the CLI's)."""
    scene = context.scene
    settings = scene.hhd if settings is None else settings
    bake_dir = Path(bake_session.output_folder(settings, out_dir))
    report_dir = Path(folder) if folder else bake_dir / "compare"
    receivers = bake_session.target_objects(context, objects, settings)
    groups, warnings = bake_session.atlas_groups(receivers, settings)
    camera = camera_of(scene, percentage)
    depsgraph = context.evaluated_depsgraph_get()
    bake_scene = scene_data.read_bake_scene(depsgraph)
    bare = sorted(o.name for o in receivers if not any(s.material for s in o.material_slots))
    if bare:
        warnings.append(f"{', '.join(repr(n) for n in bare)} have no material: left out of the comparison")
    seen = []
    for name, width, height, members in groups:
        kept = [o for o in members if o.name not in bare]
        if not kept:
            continue
        files = lightmap_files.AtlasFiles(bake_dir, name)
        if not files.sidecar.is_file():
            raise BakeError(f"atlas '{name}' has no bake in {bake_dir}: bake it first")
        g = core_compare.gbuffer(camera, bake_scene, mesh_data.read_surface(kept, settings.uv_layer, depsgraph))
        if len(g.index):
            pipeline = _pipeline(settings, lightmap_files.read_sidecar(files.sidecar))
            seen.append(Atlas(name, files, g, pipeline, width * height))
        else:
            warnings.append(f"atlas '{name}': none of its receivers is seen by the camera")
    if not seen:
        raise BakeError("no receiver of the baked atlases is seen by the scene camera: nothing to compare")
    return Comparison(
        scene,
        camera,
        seen,
        report_dir,
        samples=samples,
        bounces=settings.bounces,
        roughness=roughness,
        models=models,
        warnings=warnings,
    )


@dataclass
class Atlas:
    """One compared atlas: its files, its compared pixels (`core_compare.GBuffer`), the post
    stages its bake ran (`_pipeline`), its texel count."""

    name: str
    files: lightmap_files.AtlasFiles
    g: core_compare.GBuffer
    pipeline: object
    texels: int


@dataclass
class Step:
    """One step of a comparison: `message` says what it does (shown while it runs), `cost` its
    estimated microseconds (its share of the progress bar), `run()` does it."""

    message: str
    cost: float
    run: Callable[[], None]


class Comparison:
    """A comparison in steps (module doc), made by `prepare`, run by `begin` / `advance` or
    `run_steps`. `steps`, `done` (how many ran), `warnings`; `summary` once the last one ran."""

    def __init__(
        self, scene, camera, seen: list[Atlas], report_dir: Path, *, samples, bounces, roughness, models, warnings
    ):
        self.scene, self.camera, self.seen, self.report_dir = scene, camera, seen, report_dir
        self.samples, self.bounces = samples, bounces
        self.roughness, self.models, self.warnings = tuple(roughness), tuple(models), warnings
        self.renders: dict = {}  # (pass key, seed) → (H, W, 3)
        self.references: dict = {}
        self.halves: dict = {}
        self.rows: list = []
        self.images: dict = {}
        self.summary = ""
        self.check: Callable[[], None] | None = None  # a denoise's cancel check (`advance`)
        self.callback: Callable[[float, str], None] | None = None
        self.progress = core_progress.Progress(self._report)  # the fractions and the ETA
        self._post: tuple | None = None  # the atlas being encoded: (data, records, seams)
        self._tmp: tempfile.TemporaryDirectory | None = tempfile.TemporaryDirectory(prefix="hhd-compare-")
        self.steps = self._render_steps() + self._atlas_steps() + [self._report_step()]
        self.done = 0

    def _passes(self) -> list[tuple]:
        """(key, roughness, glossy, label) of each reference."""
        return [("diffuse", 0.0, False, "diffuse")] + [(r, r, True, f"glossy r={r:g}") for r in self.roughness]

    def _render_steps(self) -> list[Step]:
        half = max(1, self.samples // 2)
        cost = COST_RENDER_START + self.camera.width * self.camera.height * half * COST_RENDER_SAMPLE * (
            1 + self.bounces
        )
        runs = [(key, r, glossy, label, seed) for key, r, glossy, label in self._passes() for seed in (1, 2)]
        steps = []
        for k, run in enumerate(runs):
            label, seed = run[3], run[4]
            steps.append(
                Step(f"Cycles reference {k + 1}/{len(runs)}: {label}, seed {seed}", cost, partial(self._render, *run))
            )
        return steps

    def _atlas_steps(self) -> list[Step]:
        steps = []
        for atlas in self.seen:
            post = [
                name
                for name, on in (("denoise", atlas.pipeline.denoise), ("stitch", atlas.pipeline.stitch_seams))
                if on
            ]
            cost = atlas.texels * (core_progress.COST_IMAGE + sum(core_progress.POST_COSTS[n] for n in post))
            stages = f" ({', '.join(post)})" if post else ""
            steps.append(Step(f"reading atlas '{atlas.name}'{stages}", cost, partial(self._read_atlas, atlas)))
            for model in self.models:
                lobes = int(model[2:]) if model.startswith("sg") else 0
                cost = atlas.texels * (core_progress.COST_ENCODE + lobes * COST_SG_LOBE)
                steps.append(
                    Step(f"encoding atlas '{atlas.name}' as {model}", cost, partial(self._encode, atlas, model))
                )
        return steps

    def _report_step(self) -> Step:
        pixels = self.camera.width * self.camera.height * (len(self.models) + 1) * (len(self.roughness) + 1)
        return Step(f"writing the report into {self.report_dir}", pixels * COST_REPORT_PIXEL, self._write_report)

    def _render(self, key, roughness: float, glossy: bool, label: str, seed: int) -> None:
        assert self._tmp is not None, "the comparison was closed"
        path = Path(self._tmp.name) / f"reference_{key}_{seed}.exr"
        with reference_setup(self.scene, self.camera, max(1, self.samples // 2), self.bounces):
            try:
                self.renders[key, seed] = _render(self.scene, path, roughness, glossy, seed)
            except (RuntimeError, BakeError) as exc:
                detail = " ".join(str(exc).replace("Error:", "").split())
                raise BakeError(f"the Cycles reference render ({label}, seed {seed}) failed: {detail}") from exc
        path.unlink(missing_ok=True)

    def _read_atlas(self, atlas: Atlas) -> None:
        """The atlas's raw SH after its post stages (`core_compare.post_stages`)."""
        if not self.references:  # every render done: the references and their noise
            for key, *_ in self._passes():
                a, b = self.renders.pop((key, 1)), self.renders.pop((key, 2))
                self.references[key], self.halves[key] = 0.5 * (a + b), 0.5 * (a - b)
        data = lightmap_files.read_texel_data(atlas.files)
        seams = lightmap_files.read_seams(atlas.files, data.atlas_shape) if atlas.pipeline.stitch_seams else None
        raw_sh = partial(lightmap_files.read_sh, atlas.files.sh)  # read back if OIDN fails half-way
        data, records = core_compare.post_stages(data, atlas.pipeline, seams, self.check, raw_sh)
        self._post = (data, records, seams)
        self.images.setdefault("reference", []).append((atlas.g, None))

    def _encode(self, atlas: Atlas, model: str) -> None:
        assert self._post is not None
        data, records, seams = self._post
        rec = core_compare.reconstruct_model(model, data, records, atlas.pipeline, seams, atlas.g, self.roughness)
        self.rows.append(_row(atlas.name, rec, atlas.g, self.references, self.halves, self.roughness))
        self.images.setdefault(rec.model, []).append((atlas.g, rec))
        if model == self.models[-1]:
            self._post = None

    def _write_report(self) -> None:
        _write(self.report_dir, self.rows, self.images, self.references, self.roughness, self.camera, self.samples)
        measured = [r for r in self.rows if math.isfinite(r["diffuse"])]
        top = min(measured, key=lambda r: r["diffuse"]) if measured else None
        best = f": lowest diffuse error {top['model']} {100 * top['diffuse']:.1f}%" if top else ""
        self.summary = (
            f"Compared {len(set(r['model'] for r in self.rows))} encodings against Cycles ({self.camera.width}×"
            f"{self.camera.height}, {self.samples} samples) in {self.report_dir}{best}"
        )

    def _report(self, fraction: float, message: str) -> None:
        if self.callback is not None:
            self.callback(fraction, message)

    def announce(self) -> None:
        """Report the step about to run (its start, its message), or 1.0 once all ran."""
        if self.done < len(self.steps):
            spent = sum(step.cost for step in self.steps[: self.done])
            self.progress.report(spent / sum(step.cost for step in self.steps), self.steps[self.done].message)
        else:
            self.progress.finish(f"compare: report written to {self.report_dir}")

    def close(self) -> None:
        """Delete the temporary renders and drop what the steps hold (any time; again is a no-op)."""
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        self.renders, self._post = {}, None


def begin(job: Comparison, progress: Callable[[float, str], None]) -> None:
    """Report the first step to `progress(fraction, message)` before `advance` runs it."""
    job.callback = progress
    job.announce()


def advance(job: Comparison, progress: Callable[[float, str], None], cancel: Callable[[], bool]) -> bool:
    """Run the next step of `job`, then report the one after it to `progress` (1.0 after the
    last); True while steps remain. `cancel()` True: BakeCancelled instead of the step (and
    within a denoise). When this raises or returns False the job is closed; the scene is as it
    was whenever it returns or raises, and the report is written only by the last step."""

    def check() -> None:
        if cancel():
            raise BakeCancelled("compare cancelled")

    job.callback, job.check = progress, check
    try:
        check()
        job.steps[job.done].run()
        job.done += 1
        job.announce()
    except BaseException:
        job.close()
        raise
    if job.done < len(job.steps):
        return True
    job.close()
    return False


def run_steps(
    job: Comparison, progress: Callable[[float, str], None], cancel: Callable[[], bool] | None = None
) -> tuple[str, list[str]]:
    """Run every step of `job` (`begin`, then `advance` until done): (summary line, warnings)."""
    stop = cancel or (lambda: False)
    try:
        begin(job, progress)
        while advance(job, progress, stop):
            pass
    finally:
        job.close()
    return job.summary, job.warnings


def _pipeline(settings, sidecar: dict):
    """The bake's post stages as its sidecar records them (denoise through Blender's OIDN,
    `denoiser.oidn_library`), with the scene's encoder settings."""
    post_ = sidecar.get("post", {})
    denoise = bool(post_.get("denoise", {}).get("enabled", False))
    return replace(
        bake_settings.pipeline_settings(settings),
        denoise=denoise,
        denoiser_library=denoiser.oidn_library() if denoise else "",
        stitch_seams=bool(post_.get("stitch", {}).get("enabled", False)),
    )


def _row(atlas: str, rec, g, references: dict, halves: dict, roughness) -> dict:
    """One table row: per term the error with the reference's own noise left out in quadrature
    (`core_compare.noise_removed`), and that noise ("<term>_reference_noise")."""
    pixels = lambda image: image.reshape(-1, 3)[g.index]
    row = {"atlas": atlas, "model": rec.model, "bytes_per_texel": rec.bytes_per_texel, "pixels": int(len(g.index))}
    for key, name, values in [("diffuse", "diffuse", rec.diffuse)] + [
        (r, f"specular_{r:g}", rec.specular.get(r)) for r in roughness
    ]:
        reference = pixels(references[key])
        floor = core_compare.relative_rmse(reference + pixels(halves[key]), reference)
        row[f"{name}_reference_noise"] = floor
        row[f"{name}_reference_mean"] = float(np.mean(reference @ LUMINANCE))
        if values is None:
            row[name] = None
            continue
        row[f"{name}_raw"] = core_compare.relative_rmse(values, reference)
        row[name] = core_compare.noise_removed(row[f"{name}_raw"], floor)
    return row


def _write(folder: Path, rows, images, references, roughness, camera, samples) -> None:
    heads = ["atlas", "encoding", "bytes/texel", "diffuse error"] + [f"specular error α=r², r={r:g}" for r in roughness]
    lines = [
        "# Encodings against Cycles (HHD Lightmapper compare)",
        "",
        f"Scene camera, {camera.width}×{camera.height} pixels, Cycles {samples} samples (clamps off; two renders "
        "of half as many with other seeds, averaged). Error: relative RMSE of the luminance over the compared "
        "pixels (receivers seen from the front, away from object edges), over the reference's mean, with the "
        "reference's own noise (half the two renders' difference; the last row) left out in quadrature. "
        "Specular: F0 = 1; — where the encoding does not model it.",
        "",
        "| " + " | ".join(heads) + " |",
        "|" + " --- |" * len(heads),
    ]
    for r in rows:
        spec = [r[f"specular_{x:g}"] for x in roughness]
        cells = [r["atlas"], r["model"], str(r["bytes_per_texel"]), _percent(r["diffuse"])]
        cells += [_percent(s) for s in spec]
        lines.append("| " + " | ".join(cells) + " |")
    for atlas in dict.fromkeys(r["atlas"] for r in rows):
        r = next(x for x in rows if x["atlas"] == atlas)
        noise = [r["diffuse_reference_noise"]] + [r[f"specular_{x:g}_reference_noise"] for x in roughness]
        lines.append("| " + " | ".join([atlas, "reference noise", "", *(_percent(n) for n in noise)]) + " |")
    order = ["reference"] + [m for m in images if m != "reference"]
    lines += ["", "contact_sheet.png rows, top to bottom: " + ", ".join(order) + "; columns: diffuse, "
              + ", ".join(f"specular r={r:g}" for r in roughness) + "."]  # fmt: skip
    finite = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()} for r in rows]
    sheet = png_encode(_sheet(order, images, references, roughness))
    with exr.Staging() as staging:  # all three replace the old report together, or none does
        staging.write_text(folder / "compare.md", "\n".join(lines) + "\n")
        staging.write_text(folder / "compare.json", json.dumps({"rows": finite}, indent=1, allow_nan=False) + "\n")
        staging.stage(folder / "contact_sheet.png").write_bytes(sheet)
        staging.commit()


def _percent(value) -> str:
    """A table cell: '12.34%', '—' for a term the encoding does not model, 'n/a' where the
    reference is black there (no relative error)."""
    if value is None:
        return "—"
    return f"{100 * value:.2f}%" if math.isfinite(value) else "n/a"


def _sheet(order, images, references, roughness) -> np.ndarray:
    """The contact sheet (module doc) as an 8-bit sRGB image."""
    keys = ["diffuse", *roughness]
    scale = {k: 0.18 / max(float(np.mean(references[k] @ [0.2126, 0.7152, 0.0722])), 1e-12) for k in keys}
    rows = []
    for model in order:
        cells = []
        for k in keys:
            if model == "reference":
                cell = references[k].copy()
                mask = np.zeros(cell.shape[:2], bool)
                for g, _ in images["reference"]:
                    mask.reshape(-1)[g.index] = True
                cell[~mask] = 0.0
            else:
                cell = np.zeros_like(references["diffuse"])
                for g, rec in images[model]:
                    values = rec.diffuse if k == "diffuse" else rec.specular.get(k)
                    if values is not None:
                        cell.reshape(-1, 3)[g.index] = values
            cells.append(cell * scale[k])
        rows.append(np.concatenate(cells, axis=1))
    linear = np.clip(np.concatenate(rows, axis=0), 0.0, 1.0)
    srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
    return np.round(srgb * 255).astype(np.uint8)
