"""One lazy compiler for the numba kernels of every module that has them. No bpy.

A kernel module writes its per-sample loops as plain Python functions and declares them once:

    KERNELS = compiled.KernelSet(__name__, kernels=("advance_paths",), uses=(sampling.KERNELS,))
    get = KERNELS.get

Nothing compiles until `get()` is first called (numba is imported then, through `deps`, so a
module imports without numba). Compiling a set first compiles the sets it `uses`, then rebinds,
in the module's globals, every function another set compiled (imported with `from … import`)
and the module's own `helpers` to their compiled versions, so the kernels call compiled code;
then it compiles the `kernels` and returns them by name. The options are the tracer's:
`nogil` (worker threads run kernels in parallel), `cache` (only the first bake after an install
compiles), numpy's error model (a division by zero gives inf or NaN, as numpy does); helpers that
make no array are compiled without reference counting (`_nrt=False`: otherwise every per-sample
call counts each array it is passed up and down, atomically); `allocating` names those that do.
Helpers named in `inline` are inlined into their callers by numba (`inline="always"`, before
LLVM sees them): otherwise each is a call LLVM cannot inline, passing every array argument
field by field, and in a per-sample loop those calls cost more than small helpers' arithmetic.
Inlining changes no arithmetic (the same operations in the same order; no fast-math).

numba's disk cache checks only the source file of the function it compiled: after editing a
helper another module's kernels call, delete that module's cache (`__pycache__/*.nbi`, `*.nbc`).
"""

from __future__ import annotations

import sys
import threading
from types import SimpleNamespace

from . import deps

#: id(plain function) → (the function, its compiled dispatcher), over every compiled set
_COMPILED: dict[int, tuple[object, object]] = {}
_lock = threading.RLock()


class KernelSet:
    """The numba kernels of `module` (its __name__): `kernels` entry points, `helpers` they call
    (compiled first), `allocating` the helpers that make arrays, `uses` the sets whose helpers
    this module imports, `inline` the helpers inlined into their callers."""

    def __init__(
        self,
        module: str,
        kernels: tuple[str, ...],
        helpers: tuple[str, ...] = (),
        allocating: tuple[str, ...] = (),
        uses: tuple[KernelSet, ...] = (),
        inline: tuple[str, ...] = (),
    ):
        self.module, self.kernels, self.helpers = module, kernels, helpers
        self.allocating, self.uses, self.inline = allocating, uses, inline
        self._compiled: SimpleNamespace | None = None

    def get(self) -> SimpleNamespace:
        """The compiled kernels (numba.njit, nogil, cached on disk), by name. Raises
        DependencyMissing naming numba if it is not installed."""
        with _lock:
            if self._compiled is None:
                for other in self.uses:
                    other.get()
                self._compiled = self._compile()
        return self._compiled

    def _compile(self) -> SimpleNamespace:
        numba = deps.require("numba")
        jit = numba.njit(nogil=True, cache=True, error_model="numpy")
        borrow = numba.njit(nogil=True, cache=True, error_model="numpy", _nrt=False)
        inlined = numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
        module = vars(sys.modules[self.module])
        for name, value in list(module.items()):  # helpers of other sets, imported by name
            if id(value) in _COMPILED and _COMPILED[id(value)][0] is value:
                module[name] = _COMPILED[id(value)][1]
        for name in self.helpers:
            plain = module[name]
            if id(plain) not in _COMPILED:  # a helper two sets bind (e.g. sh.basis) compiles once
                how = inlined if name in self.inline else jit if name in self.allocating else borrow
                _COMPILED[id(plain)] = (plain, how(plain))
            module[name] = _COMPILED[id(plain)][1]
        out = {}
        for name in self.kernels:
            plain = module[name]
            out[name] = jit(plain)
            _COMPILED[id(plain)] = (plain, out[name])
        return SimpleNamespace(**out)
