"""Pickling for the farm's workers: this package's classes and functions named as a worker
imports them (`hhd_lightmapper`, where Blender's is `bl_ext.<repo>.hhd_lightmapper`), and the
estimator shipped as its plain state (`ship`). No bpy."""

from __future__ import annotations

import hashlib
import importlib
import io
import pickle
import types

from ..tracer import shipping

#: The package name workers import (`pip install ".[farm]"` installs it under this name).
WORKER_PACKAGE = "hhd_lightmapper"


#: This process's name of the package: WORKER_PACKAGE, or Blender's `bl_ext.<repo>.hhd_lightmapper`.
PACKAGE = __name__[: -len(".core.farm.names")]


def _worker_module(module: str) -> str | None:
    """The worker's name of one of this package's modules; None for other modules."""
    if module == PACKAGE or module.startswith(PACKAGE + "."):
        return WORKER_PACKAGE + module[len(PACKAGE) :]
    return None


class _Module:
    """A module by name: pickled as `importlib.import_module(name)`."""

    def __init__(self, name: str):
        self.name = name

    def __reduce__(self):
        return importlib.import_module, (self.name,)


class _Named:
    """A module-level function `name` of this package's module `module`: callable here, pickled
    as the worker package's function of that name (pickle and cloudpickle would otherwise name
    this process's module, which a worker outside Blender cannot import)."""

    def __init__(self, module: str, name: str):
        self.module, self.__name__ = module, name
        self.function = getattr(importlib.import_module(module), name)

    def __call__(self, *args, **kwargs):
        return self.function(*args, **kwargs)

    def __reduce__(self):
        return getattr, (_Module(_worker_module(self.module) or self.module), self.__name__)


class _Pickler(pickle.Pickler):
    """Pickles with this package's classes and functions named as the workers import them, and a
    `Shipped` context as its plain state (no live Embree objects)."""

    def reducer_override(self, obj):
        if isinstance(obj, shipping.Shipped):
            return _Named(shipping.__name__, "_receive"), ship(obj)
        if PACKAGE != WORKER_PACKAGE and isinstance(obj, type | types.FunctionType):
            module = _worker_module(getattr(obj, "__module__", None) or "")
            if module is not None and "." not in obj.__qualname__:
                return getattr, (_Module(module), obj.__qualname__)
        return NotImplemented


def ship(obj: shipping.Shipped) -> tuple[str, bytes]:
    """(digest, payload) of a Shipped context, `shipping._receive(digest, payload)` rebuilding it
    in a worker: its state without live attributes, pickled with worker names."""
    state = {k: v for k, v in obj.__dict__.items() if k not in obj._live and k != "_shipped"}
    payload = dumps((type(obj), state))
    return hashlib.blake2b(payload, digest_size=16).hexdigest(), payload


def dumps(obj) -> bytes:
    buffer = io.BytesIO()
    _Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buffer.getvalue()


def plain(obj):
    """This package's dataclass instances (nested, also inside dicts, lists and tuples) as dicts
    naming their class relative to the package, its classes and functions as dicts naming them
    the same way, everything else as it is: what a worker returns
    to a client that may name the package otherwise (`unplain` there)."""
    cls = type(obj)
    if cls is dict:
        return {k: plain(v) for k, v in obj.items()}
    if cls is list or cls is tuple:
        return cls(plain(v) for v in obj)
    module = getattr(cls, "__module__", "") or ""
    if hasattr(obj, "__dataclass_fields__") and _worker_module(module) is not None:
        return {"__class__": (module[len(PACKAGE) :], cls.__qualname__), **{k: plain(v) for k, v in vars(obj).items()}}
    module = getattr(obj, "__module__", "") or ""
    if isinstance(obj, type | types.FunctionType) and _worker_module(module) is not None:
        return {"__object__": (module[len(PACKAGE) :], obj.__qualname__)}  # e.g. a Channel's `pack`
    return obj


def unplain(obj):
    """The inverse of `plain`, with this process's classes."""
    cls = type(obj)
    if cls is dict and "__class__" in obj:
        module, name = obj["__class__"]
        cls = getattr(importlib.import_module(PACKAGE + module), name)
        instance = cls.__new__(cls)
        instance.__dict__.update({k: unplain(v) for k, v in obj.items() if k != "__class__"})
        return instance
    if cls is dict and "__object__" in obj:
        module, name = obj["__object__"]
        found = importlib.import_module(PACKAGE + module)
        for part in name.split("."):
            found = getattr(found, part)
        return found
    if cls is dict:
        return {k: unplain(v) for k, v in obj.items()}
    if cls is list or cls is tuple:
        return cls(unplain(v) for v in obj)
    return obj
