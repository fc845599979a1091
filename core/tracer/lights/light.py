"""The interface every light of the tracer implements (`Light`) and the numbers its samples draw
(`uniforms`: per group, per texel `TexelStream`, per row `RowStream`, `Subset`). No bpy."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ... import sampling

#: A light sample at R points: directions (R, 3), value (R, 3) (radiance × solid angle, or
#: radiance × MIS weight / pdf), distances (R,) to the sampled point (inf: a direction).
Sample = tuple[np.ndarray, np.ndarray, np.ndarray]


#: Density per steradian (R,) of the strategy that samples rays at the shading points, at
#: directions (R, 3): the other strategy an MIS weight is taken against.
RayPdf = Callable[[np.ndarray], np.ndarray]


class Light(ABC):
    """One source of light. group: the light group it belongs to ("": the default set);
    column: the first of the 3 radiance columns of its light set (`paths.TraceScene` sets it);
    reachable: rays can also reach it (MIS with `pdf` and `evaluate`), else next-event
    estimation only; at_infinity: reached by rays leaving the scene, not by hitting triangles."""

    group: str = ""
    column: int = 0
    reachable: bool = False
    at_infinity: bool = False
    #: one of the lights a shading point picks from (`Choice`), rather than sampled at every point
    chosen: bool = False

    @abstractmethod
    def sample(
        self,
        rng: np.random.Generator,
        x: np.ndarray,
        ray_pdf: RayPdf,
        strata: Strata = 1,
        normals: np.ndarray | None = None,
    ) -> Sample:
        """One sample per shading point x (R, 3), drawn from `rng` (see `Sample`); a reachable
        light weights it against `ray_pdf`, the others ignore it. strata: x comes in groups of
        that many points of one texel, whose random numbers are stratified together
        (`uniforms`); normals (R, 3): the points' normals, for lights that favour what lies above
        the horizon (`pdf` and `evaluate` must then get the same)."""

    def pdf(
        self,
        d: np.ndarray,
        t: np.ndarray | None = None,
        prim: np.ndarray | None = None,
        origins: np.ndarray | None = None,
        normals: np.ndarray | None = None,
    ) -> np.ndarray:
        """Density per steradian (R,) with which `sample` at `origins` (R, 3) with `normals` picks
        the point a ray along d (R, 3) reached (at distance t (R,) on triangle prim (R,), where
        that applies); 0 for a light rays never reach."""
        return np.zeros(len(d))

    def evaluate(
        self,
        d: np.ndarray,
        t: np.ndarray | None,
        prim: np.ndarray | None,
        pdf: np.ndarray,
        origins: np.ndarray | None = None,
        normals: np.ndarray | None = None,
    ) -> np.ndarray:
        """Radiance (R, 3) that rays from `origins` (R, 3) (with `normals`) along d (R, 3), sampled with density
        `pdf` (R,), bring from this light (ending at distance t on triangle prim, where that
        applies), MIS-weighted against `sample`; 0 for a light rays never reach."""
        return np.zeros((len(d), 3))

    def reached(self, prim: np.ndarray) -> np.ndarray:
        """The rows (int64) of the rays ending on triangles prim (R,) (−1: a miss) that reached
        this light by hitting it: none, but for emitting triangles."""
        return np.zeros(0, np.int64)

    def choice_row(self) -> list[float]:
        """A `chosen` light's row of `Choice.table` (`light_kernels.choose_lights`)."""
        raise NotImplementedError(f"{type(self).__name__} is not one of the lights a point chooses from")

    @property
    @abstractmethod
    def power(self) -> float:
        """Luminance of the light's emitted power: W for lights at a finite distance; for lights
        at infinity ∫ L dω over their directions, W/m² (a sun: its irradiance at normal incidence)."""


@dataclass
class Subset:
    """The numbers of some rows (R',) of n points, each as `strata` gives it for all n: a light
    sampled only at the points that chose it (`Choice`) draws what it would have drawn there.
    `drawn` (dimension → (n,) numbers) is shared by the lights of one choice, whose rows are
    disjoint: each dimension is drawn once for all of them."""

    strata: Strata
    n: int
    rows: np.ndarray
    rng: np.random.Generator
    drawn: dict[int, np.ndarray] = field(default_factory=dict)

    def uniforms(self, dim: int) -> np.ndarray:
        if dim not in self.drawn:
            self.drawn[dim] = uniforms(self.rng, self.n, self.strata, dim)
        return self.drawn[dim][self.rows]


@dataclass(frozen=True)
class TexelStream:
    """Where a pass's light samples come from when they are grouped by texel: the texels (n,)
    (bake point ids), k samples each, the pass's first sample index (pass × k) and the bake's
    seed. `uniforms` then takes dimension `dim` of each texel's own sequence
    (`sampling.texel_sequence`), stratified across every pass of the texel, not only this one."""

    texels: np.ndarray
    k: int
    first: int
    seed: int

    def uniforms(self, dim: int) -> np.ndarray:
        texels = np.ascontiguousarray(self.texels, np.int64)
        return sampling.get().texel_sequence(texels, self.k, self.first, dim, self.seed)


@dataclass
class RowStream:
    """Where the light samples of some rows of a pass come from: rows (R,) of the pass's
    samples (row t·k + j: sample j of texel `texels[t]`, global ids (n,)), k samples per texel,
    the pass's first sample index (pass × k), the bake's seed and the first stream number.
    `uniforms(dim)` takes each row's number from its texel's own (0,2)-sequence for the pair of
    dimensions dim // 2 (`sampling.row_sequence`), stratified across every pass of the texel:
    the light sample at a path's first bounce, say, is stratified like the texel's own."""

    rows: np.ndarray
    texels: np.ndarray
    k: int
    first: int
    seed: int
    stream: int
    _pair: tuple[int, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def uniforms(self, dim: int) -> np.ndarray:
        stream = self.stream + dim // 2
        if self._pair is None or self._pair[0] != stream:  # dims 2j and 2j + 1 share one pair
            rows = np.ascontiguousarray(self.rows, np.int64)
            texels = np.ascontiguousarray(self.texels, np.int64)
            self._pair = (stream, sampling.get().row_sequence(rows, texels, self.k, self.first, self.seed, stream))
        return self._pair[1][dim % 2]


#: `Light.sample`'s strata: a group size (int), a TexelStream, a RowStream or a Subset of one.
Strata = int | TexelStream | RowStream | Subset


def uniforms(rng: np.random.Generator, n: int, strata: Strata = 1, dim: int = 0) -> np.ndarray:
    """(n,) uniform numbers in [0, 1) for dimension `dim` of a light's sampling. A TexelStream:
    its texels' own sequences (n must be its texels × k); a RowStream: its rows' (n rows). An int > 1 (and n a multiple of it):
    each group of `strata` consecutive numbers is stratified, one in each [j/strata,
    (j+1)/strata), in random order (a Latin hypercube when several dimensions are drawn so).
    Either way each number is still uniform, so estimates stay unbiased, while a texel's light
    samples cover the light evenly."""
    if isinstance(strata, (TexelStream, RowStream, Subset)):
        return strata.uniforms(dim)
    if strata <= 1 or n % strata:
        return rng.random(n)
    order = np.argsort(rng.random((n // strata, strata)), axis=1)
    return ((order + rng.random((n // strata, strata))) / strata).reshape(n)


def _rows(a: np.ndarray | None) -> np.ndarray:
    """`a` (R, 3) as contiguous float64 for the kernels; None as no rows (0, 3)."""
    return np.zeros((0, 3)) if a is None else np.ascontiguousarray(a, np.float64)
