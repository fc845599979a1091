"""Bake what changed: the stale report and a bake of some receivers into the existing files.

`stale_report(context)` compares the scene's fingerprints now with the last bake's in the
output folder (`core.incremental`), changing nothing. `IncrementalSession` is `BakeSession`'s
counterpart for a subset (same interface: `describe`, `run`, `finish`, warnings): its receivers
are the last bake's (every object listed in the output folder's atlas sidecars), of which it
re-traces those named (`mode` "only"), those that changed ("changed") or those that changed and
those the changes influence ("influenced", `core.incremental.fingerprints.influenced`).
"""

from __future__ import annotations

from pathlib import Path

from ..core import bake as core_bake
from ..core.errors import FullBakeNeeded
from ..core.files import lightmap_files
from ..core.incremental import fingerprints as core_fingerprints
from ..core.incremental import subset as core_subset
from . import bake_session, collection_instances, fingerprints, mesh_data, scene_data
from . import settings as bake_settings

MODES = ("only", "changed", "influenced")


def baked_atlases(out_dir: str) -> dict[str, dict]:
    """{atlas name: sidecar} of the atlases baked into `out_dir` (not light sets or probes)."""
    from pathlib import Path

    out = {}
    folder = Path(out_dir)
    if not folder.is_dir():
        return out
    for path in sorted(folder.glob("*.json")):
        try:
            doc = lightmap_files.read_sidecar(path)
        except Exception:  # not a sidecar (probes.json, anything else): not an atlas
            continue
        if "light_set" in doc or "objects" not in doc or doc.get("atlas") != path.stem:
            continue
        out[path.stem] = doc
    return out


def _last_bake(context, out_dir: str, settings):
    """(receivers of the last bake, atlas groups now, the last bake's fingerprints or None,
    the scene's fingerprints now), `settings` the scene's HHD settings or an `Overridden` view.
    FullBakeNeeded without an earlier bake or when a receiver of it is gone."""
    atlases = baked_atlases(out_dir)
    if not atlases:
        raise FullBakeNeeded(f"no earlier bake in {out_dir}: bake all first")
    names = list(dict.fromkeys(o["name"] for doc in atlases.values() for o in doc["objects"]))
    found = {n: collection_instances.find(n) for n in names}
    gone = [n for n, o in found.items() if o is None or o.type != 'MESH']
    if gone:
        raise FullBakeNeeded(f"{', '.join(repr(n) for n in gone)}: baked last time but no longer a mesh here: bake all")
    receivers = list(found.values())
    groups, _ = bake_session.atlas_groups(receivers, settings)
    old, _ = core_fingerprints.folder_state(out_dir, list(atlases))
    now = fingerprints.scene_fingerprints(context, groups, settings.uv_layer)
    return receivers, groups, old, now


def stale_report(
    context, out_dir: str | None = None, settings=None
) -> tuple[core_fingerprints.Stale | None, list[str]]:
    """What changed since the last bake into the output folder (`out_dir` or the Output Folder
    setting): the Stale (None when there is no earlier bake with fingerprints) and its lines for
    the panel and the console. `settings`: the scene's HHD settings (None) or an `Overridden` view
    of them (the CLI's), for the folder, the atlas sizes and the UV layer. Reads the scene and the
    sidecars only."""
    settings = context.scene.hhd if settings is None else settings
    folder = bake_session.output_folder(settings, out_dir)
    try:
        receivers, groups, old, now = _last_bake(context, folder, settings)
    except FullBakeNeeded as exc:
        return None, [str(exc)]
    if old is None:
        return None, [f"the last bake in {folder} has no fingerprints (made before they were recorded): bake all"]
    stale = core_fingerprints.compare(old, now)
    lines = stale.lines()
    if stale:
        changed = core_fingerprints.changed_receivers(stale, [o.name for o in receivers])
        influenced = core_fingerprints.influenced(stale, old, now, [o.name for o in receivers])
        lines.append(
            f"Bake Changed re-traces {len(changed)}, Changed + Influenced {len(influenced)} of {len(receivers)} receivers"
        )
    return stale, lines


class IncrementalSession:
    """A bake of some of the last bake's receivers into its files (module doc). `mode`: "only"
    (the receivers `names`), "changed" or "influenced". Raises FullBakeNeeded (nothing done) when
    there is no earlier bake, a layout changed, or a name is not a receiver of it."""

    def __init__(
        self,
        context,
        mode: str,
        names: list[str] | None = None,
        out_dir: str | None = None,
        threads: int | None = None,
        settings=None,
    ):
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}: one of {MODES}")
        settings = context.scene.hhd if settings is None else settings
        self.settings = bake_settings.scene_settings(context.scene, threads, settings)
        self.out_dir = bake_session.output_folder(settings, out_dir)
        self.mode = mode
        self.warnings: list[str] = []
        receivers, groups, old, now = _last_bake(context, self.out_dir, settings)
        self.receivers, self.old, self.now = receivers, old, now
        if old is not None:
            changed_layouts = [a for a in now.layout if old.layout.get(a) not in (None, now.layout[a])]
            if changed_layouts:
                raise FullBakeNeeded(
                    f"the layout of atlas {', '.join(repr(a) for a in changed_layouts)} changed since the last bake "
                    "(unwrapped again): bake all"
                )
        elif mode != "only":
            raise FullBakeNeeded("the last bake has no fingerprints (made before they were recorded): bake all")
        all_names = [o.name for o in receivers]
        if mode == "only":
            names = [m.name for m in collection_instances.receivers_named(names or [])]
            missing = [n for n in names if n not in all_names]
            if missing or not names:
                raise FullBakeNeeded(
                    f"{', '.join(repr(n) for n in missing) or 'no object named'}: not a receiver of the last bake in "
                    f"{self.out_dir}: bake all (or bake it with its atlas)"
                )
            chosen = [n for n in all_names if n in set(names)]
        else:
            stale = core_fingerprints.compare(old, now)
            chosen = (
                core_fingerprints.changed_receivers(stale, all_names)
                if mode == "changed"
                else core_fingerprints.influenced(stale, old, now, all_names)
            )
        self.chosen = chosen
        depsgraph = context.evaluated_depsgraph_get()
        cache = mesh_data.TextureCache()
        notes: list[str] = []
        self.scene = scene_data.read_bake_scene(depsgraph) if chosen else None
        self.atlases, self.only = [], {}
        for name, width, height, members in groups:
            mine = [o for o in members if o.name in set(chosen)]
            if not mine:
                continue
            surface = mesh_data.read_surface(mine, settings.uv_layer, depsgraph, cache, notes)
            order = [o.name for o in members]
            surface.object_index = _remap(surface.object_index, [order.index(o.name) for o in mine])
            self.atlases.append(core_bake.AtlasInput(name, width, height, surface, order))
            self.only[name] = [o.name for o in mine]
        self.warnings += list(dict.fromkeys(notes + (self.scene.notes if self.scene else [])))
        self.results: list[core_subset.SubsetResult] = []
        self.seconds = 0.0

    def describe(self) -> str:
        what = {"only": "the named", "changed": "changed", "influenced": "changed and influenced"}[self.mode]
        names = ", ".join(self.chosen) if self.chosen else "none"
        return f"{what} receivers: {names} ({len(self.chosen)} of {len(self.receivers)})"

    def run(self, progress=None, cancel=None, farm=None) -> list[core_subset.SubsetResult]:
        """Re-trace the chosen receivers into the files (core work only, worker-thread safe)."""
        import time

        if not self.chosen:
            self.results = []
            return self.results
        t = time.perf_counter()
        everything = self.mode == "influenced"

        def record(atlas: str, names: list[str]) -> dict:
            base = self.old if self.old is not None else self.now
            return {"fingerprints": core_fingerprints.consumed(base, self.now, names, everything).to_json()}

        self.results = core_subset.bake_subset(
            self.atlases, self.only, self.scene, self.settings, self.out_dir, record, progress, cancel
        )
        self.seconds = time.perf_counter() - t
        return self.results

    def finish(self) -> str:
        """Reload the written atlases' images; a one-line summary."""
        if not self.chosen:
            return f"nothing to re-trace in {self.out_dir}: no receiver changed"
        for result in self.results:
            bake_session.load_atlas_images(lightmap_files.AtlasFiles(Path(self.out_dir), result.name))
        traced = sum(r.texels for r in self.results)
        total = sum(r.atlas_texels for r in self.results)
        written = sum(r.written for r in self.results)
        return (
            f"Re-traced {', '.join(self.chosen)}: {traced} of {total} texels ({100 * traced / max(total, 1):.1f}%), "
            f"{written} written, into {len(self.results)} atlas(es) in {self.out_dir} ({self.seconds:.1f} s)"
        )

    @property
    def inward_warnings(self) -> list[str]:
        return []

    @property
    def result_warnings(self) -> list[str]:
        return [w for r in self.results for w in r.warnings]


def _remap(index, table):
    import numpy as np

    return np.asarray(table, dtype=np.int64)[np.asarray(index)]
