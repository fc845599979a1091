"""What lets a work unit run in another process. No bpy.

A work unit's function needs the bake's tracing context (the bake points, the BakeScene, its
lights) in the process that runs it. The context holds live objects too, the Embree scenes (the
scene's, the cover probe's), which cannot be pickled; so:
  * `Shipped`: a context object pickles to its plain state with its live attributes (`_live`)
    left out, serialised once per bake and sent with every unit; the receiving process unpickles
    it once (kept by a digest of those bytes) and rebuilds the live parts on first use (`lazy`);
  * `ray_scene(triangles)`: the Embree scene of triangles in this process, built once per
    triangle content (several contexts of one scene, e.g. its atlases, share it).
Both caches keep the last KEEP entries, so a worker that runs many units (and bakes) builds each
once. The caller's own process never goes through them: its context holds the live objects.
"""

from __future__ import annotations

import hashlib
import pickle
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import TypeVar

import numpy as np

from ..bakepoints.covers import content_key
from ..rays import RayScene

#: Contexts and Embree scenes a process keeps (an atlas's and the next one's).
KEEP = 2

T = TypeVar("T")
_lock = threading.RLock()
_received: OrderedDict = OrderedDict()  # digest -> unpickled context
_ray_scenes: OrderedDict = OrderedDict()  # triangles' content key -> RayScene


class Shipped:
    """Mixin of a context sent to worker processes: pickled once, unpickled once per process.
    `_live`: names of attributes holding live objects, dropped when pickling and None after
    unpickling (`lazy` rebuilds them)."""

    _live: tuple[str, ...] = ()

    def __reduce__(self):
        with _lock:
            shipped = self.__dict__.get("_shipped")
            if shipped is None:
                state = {k: v for k, v in self.__dict__.items() if k not in self._live and k != "_shipped"}
                payload = pickle.dumps((type(self), state), protocol=pickle.HIGHEST_PROTOCOL)
                shipped = self.__dict__["_shipped"] = (hashlib.blake2b(payload, digest_size=16).hexdigest(), payload)
        return _receive, shipped


def _receive(digest: str, payload: bytes):
    """The context pickled as `payload`: unpickled on its first arrival in this process."""
    with _lock:
        if digest in _received:
            _received.move_to_end(digest)
            return _received[digest]
        cls, state = pickle.loads(payload)
        obj = cls.__new__(cls)
        obj.__dict__.update(state)
        for name in cls._live:
            setattr(obj, name, None)
        _keep(_received, digest, obj)
        return obj


def lazy(obj, name: str, build: Callable[[], T]) -> T:
    """obj.<name>, built by build() if it is None (once, whatever the threads asking)."""
    value = getattr(obj, name)
    if value is None:
        with _lock:
            value = getattr(obj, name)
            if value is None:
                value = build()
                setattr(obj, name, value)
    return value


def ray_scene(triangles: np.ndarray) -> RayScene:
    """The Embree scene of `triangles` (T, 3, 3) in this process, built on the first request
    for triangles of this content."""
    key = content_key(triangles)
    with _lock:
        if key in _ray_scenes:
            _ray_scenes.move_to_end(key)
            return _ray_scenes[key]
        scene = RayScene(triangles)
        _keep(_ray_scenes, key, scene)
        return scene


def _keep(cache: OrderedDict, key, value) -> None:
    cache[key] = value
    while len(cache) > KEEP:
        cache.popitem(last=False)
