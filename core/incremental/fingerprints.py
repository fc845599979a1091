"""Fingerprints of what a bake's lighting depends on (`Fingerprints`), what is stale since the last
bake (`compare`, `Stale`), which receivers a change influences (`influenced`), and the last bake's
record in an output folder (`folder_state`, `consumed`). No bpy."""

from __future__ import annotations

import hashlib
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..files import lightmap_files

#: Version of the sidecar's "fingerprints" record: a record of another version is "unknown" (full bake).
FINGERPRINT_VERSION = 1
#: The influence rule's margin around a changed object: receivers whose world bounds come within
#: this many times the changed object's bounding-box diagonal of its old or new bounds are
#: influenced (its shadow and its first bounce; measured by bench/incremental.py).
OBJECT_REACH = 1.0
#: A changed point, spot or area light influences receivers where its unoccluded irradiance
#: P / (4π d²) is at least this fraction of the mean irradiance all point-like lights give at
#: the scene's diagonal (their total power / (4π D²)).
LIGHT_REACH = 0.01


def digest(*parts) -> str:
    """128-bit BLAKE2b hex digest of `parts`: arrays by dtype, shape and bytes (no copy of a
    contiguous array), anything else by its repr."""
    h = hashlib.blake2b(digest_size=16)
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(memoryview(a).cast("B"))
        else:
            h.update(repr(part).encode())
        h.update(b"\x00")
    return h.hexdigest()


@dataclass
class Fingerprints:
    """What a bake's lighting depends on. objects: per mesh object visible to render, {"hash",
    "bounds": [[x0, y0, z0], [x1, y1, z1]] world metres, "uv": the receiver's lightmap-UV digest
    (receivers only)}; lights: per light {"hash", "position": (3,) metres or None (a sun),
    "power": W (a sun's: its strength, W/m²)}, "emits": bool (an emissive material); world: digest of the world ("" none); layout: per
    atlas the digest of its size, receivers and their lightmap UVs (`layout_digest`)."""

    objects: dict[str, dict] = field(default_factory=dict)
    lights: dict[str, dict] = field(default_factory=dict)
    world: str = ""
    layout: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"version": FINGERPRINT_VERSION, "time": _now(), **asdict(self)}

    @classmethod
    def from_json(cls, doc) -> Fingerprints | None:
        """The record of a sidecar, None when it has none (a bake before fingerprints) or one of
        another version."""
        if not isinstance(doc, dict) or doc.get("version") != FINGERPRINT_VERSION:
            return None
        return cls(dict(doc["objects"]), dict(doc["lights"]), str(doc["world"]), dict(doc["layout"]))


def layout_digest(width: int, height: int, uv: dict[str, str]) -> str:
    """The layout of an atlas: its size and its receivers' lightmap-UV digests {name: digest}."""
    return digest(int(width), int(height), sorted(uv.items()))


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


@dataclass
class Stale:
    """What changed between two Fingerprints: objects (changed, added or removed mesh objects),
    lights (likewise), world, layouts (atlases whose layout changed or that are new)."""

    objects: list[str] = field(default_factory=list)
    lights: list[str] = field(default_factory=list)
    world: bool = False
    layouts: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.objects or self.lights or self.world or self.layouts)

    def lines(self) -> list[str]:
        """One line per kind of change, for the panel and the console."""
        out = []
        if self.layouts:
            out.append(f"layout changed (full bake needed): {', '.join(self.layouts)}")
        if self.objects:
            out.append(f"objects: {', '.join(self.objects)}")
        if self.lights:
            out.append(f"lights: {', '.join(self.lights)}")
        if self.world:
            out.append("world")
        return out or ["nothing changed since the last bake"]


def compare(old: Fingerprints, new: Fingerprints) -> Stale:
    """What changed from `old` (the last bake's) to `new` (the scene's now): sorted names."""

    def changed(a: dict, b: dict) -> list[str]:
        return sorted(k for k in set(a) | set(b) if (a.get(k) or {}).get("hash") != (b.get(k) or {}).get("hash"))

    layouts = sorted(k for k in new.layout if old.layout.get(k) != new.layout[k])
    return Stale(changed(old.objects, new.objects), changed(old.lights, new.lights), old.world != new.world, layouts)


def changed_receivers(stale: Stale, receivers: list[str]) -> list[str]:
    """The receivers whose own fingerprint changed (geometry, transform, material)."""
    mine = set(stale.objects)
    return [r for r in receivers if r in mine]


def _bounds(entry: dict | None) -> np.ndarray | None:
    if not entry or entry.get("bounds") is None:
        return None
    return np.asarray(entry["bounds"], dtype=np.float64)


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance (m) between two axis-aligned boxes (2, 3); 0 where they overlap."""
    d = np.maximum(0.0, np.maximum(a[0] - b[1], b[0] - a[1]))
    return float(np.linalg.norm(d))


def influenced(stale: Stale, old: Fingerprints, new: Fingerprints, receivers: list[str]) -> list[str]:
    """The receivers to re-trace so that every change of `stale` is baked (the "changed +
    influenced" rule; conservative, measured by bench/incremental.py):
      * every receiver that changed itself;
      * a changed world, or a changed sun, or a light without a position, or a changed object whose
        materials emit (before or after the change): every receiver;
      * a changed (added, removed, moved, edited) object: receivers whose world bounds come within
        OBJECT_REACH × its bounding-box diagonal of its old or its new bounds (its shadow, its
        bounce light and the light it no longer blocks);
      * a changed point, spot or area light: receivers within its reach, the distance at which
        its irradiance P / (4π d²) falls to LIGHT_REACH of the mean that all point-like lights
        give at the scene's diagonal D (their total power / (4π D²)), from its old and its new
        position, taking the larger power.
    Second and later bounces beyond those distances are left stale: the rule's error."""
    if stale.world or any(_is_global(old.lights.get(n)) or _is_global(new.lights.get(n)) for n in stale.lights):
        return list(receivers)
    if any((old.objects.get(n) or {}).get("emits") or (new.objects.get(n) or {}).get("emits") for n in stale.objects):
        return list(receivers)  # an emitter changed: its light may reach anywhere
    boxes = {r: _bounds(new.objects.get(r)) for r in receivers}
    out = set(changed_receivers(stale, receivers))
    for name in stale.objects:
        for box in (_bounds(old.objects.get(name)), _bounds(new.objects.get(name))):
            if box is None:
                continue
            reach = OBJECT_REACH * float(np.linalg.norm(box[1] - box[0]))
            out |= {r for r, b in boxes.items() if b is None or _gap(b, box) <= reach}
    if stale.lights:
        scene = [b for b in boxes.values() if b is not None]
        diagonal = (
            float(np.linalg.norm(np.max([b[1] for b in scene], 0) - np.min([b[0] for b in scene], 0))) if scene else 0.0
        )
        total = sum(float(e["power"]) for fp in (new,) for e in fp.lights.values() if e.get("position") is not None)
        for name in stale.lights:
            entries = [e for e in (old.lights.get(name), new.lights.get(name)) if e]
            power = max(float(e["power"]) for e in entries)
            reach = diagonal * np.sqrt(power / max(LIGHT_REACH * total, 1e-30)) if total > 0 else np.inf
            for e in entries:
                p = np.asarray(e["position"], np.float64)
                point = np.stack([p, p])
                out |= {r for r, b in boxes.items() if b is None or _gap(b, point) <= reach}
    return [r for r in receivers if r in out]


def _is_global(entry: dict | None) -> bool:
    return entry is not None and entry.get("position") is None


def folder_state(out_dir, atlases: list[str]) -> tuple[Fingerprints | None, dict[str, dict]]:
    """The fingerprints of the last bake into `out_dir` of the atlases named (None when any has
    no sidecar or no record: no earlier bake to compare with), and each atlas's sidecar. A
    receiver's entry comes from its own atlas's sidecar, everything else from the newest record."""
    sidecars: dict[str, dict] = {}
    records = []
    for name in atlases:
        path = lightmap_files.AtlasFiles(Path(out_dir), name).sidecar
        if not path.is_file():
            return None, sidecars
        doc = lightmap_files.read_sidecar(path)
        sidecars[name] = doc
        record = doc.get("fingerprints")
        found = Fingerprints.from_json(record)
        if found is None:
            return None, sidecars
        records.append((str((record or {}).get("time", "")), name, found))
    if not records:
        return None, sidecars
    records.sort(key=lambda r: r[0])
    _, _, newest = records[-1]
    state = Fingerprints(dict(newest.objects), dict(newest.lights), newest.world, {})
    for _, name, found in records:
        state.layout[name] = found.layout.get(name, "")
        for receiver in _receivers_of(sidecars[name]):
            if receiver in found.objects:
                state.objects[receiver] = found.objects[receiver]
    return state, sidecars


def _receivers_of(sidecar: dict) -> list[str]:
    return [o["name"] for o in sidecar.get("objects", [])]


def consumed(old: Fingerprints, new: Fingerprints, names: list[str], everything: bool) -> Fingerprints:
    """The record a subset bake writes: `new` where `everything` (changed + influenced: every
    change is baked), else `old` with the objects `names` (re-traced) taken from `new`; the
    layout is `new`'s (checked equal)."""
    if everything:
        return new
    objects = dict(old.objects)
    for n in names:
        if n in new.objects:
            objects[n] = new.objects[n]
    return Fingerprints(objects, dict(old.lights), old.world, dict(new.layout))
