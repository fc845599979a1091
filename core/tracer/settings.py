"""The tracer's settings and the noise target's constants. No bpy."""

from __future__ import annotations

from dataclasses import dataclass, replace

from .. import parallel

#: The most samples per texel one pass takes (`BakeSettings.from_samples`).
MAX_PASS_SAMPLES = 16


@dataclass(frozen=True)
class BakeSettings:
    """samples: hemisphere samples per texel, rounded up to whole passes (the most a texel gets
    when a noise target or time budget stops it earlier); pass_samples: samples per texel per
    pass (the progressive step); bounces: diffuse reflections after the first hit (0 = direct
    light only); seed: makes the bake reproducible; threads: worker threads, 0 = every core this
    process may use (`parallel.resolve_threads`; the result does not depend on it; with an
    executor of the caller's, the workers it has); chunk_texels: texels per work unit (bounds
    memory: ~1 KB per texel-sample), 0 = by the atlas's size (`chunk_size`). pass_samples is a
    multiple of 4 (the directions come in two independent halves,
    `hemisphere_kernels.texel_hemisphere_rays`; 4 is the rule of the earlier estimator's four
    groups, kept so that the settings valid then stay valid).

    noise_target: 0 (off) or the relative standard error of I_z (luminance) at which a texel
    stops: after at least MIN_ADAPTIVE_PASSES passes a texel whose pass-to-pass standard error
    is below noise_target × max(its I_z, NOISE_FLOOR × the atlas mean I_z after MIN_ADAPTIVE_PASSES
    passes, fixed from then on) gets no more passes.
    The floor keeps near-black texels from asking for relative precision nobody can see.
    time_budget: 0 (off) or seconds of tracing after which no new chunk starts; the first pass
    always completes, so every texel has an estimate.

    light_sets: when the scene uses light groups, keep each light set's SH apart
    (`core.light_sets`: one trace, one result per set and their sum); off: the sum only.

    A value (frozen): the rules derived from it are defined here once, `from_samples` (the
    samples per pass for a sample count), `passes` and `worker_threads`."""

    samples: int = 256
    pass_samples: int = 16
    bounces: int = 3
    seed: int = 0
    threads: int = 0
    chunk_texels: int = 0
    noise_target: float = 0.0
    time_budget: float = 0.0
    light_sets: bool = True

    @classmethod
    def from_samples(cls, samples: int, **rest) -> BakeSettings:
        """The settings for `samples` per texel (the scene's Samples, the CLI's --samples) by the
        samples-per-pass rule: at least 4 samples, in passes of `samples` rounded up to a multiple
        of 4, at most MAX_PASS_SAMPLES each; `rest`: the other fields."""
        samples = max(4, samples)
        return cls(samples=samples, pass_samples=min(MAX_PASS_SAMPLES, -(-samples // 4) * 4), **rest)

    @property
    def passes(self) -> int:
        """The most passes a texel takes: `samples` rounded up to whole passes (at least 1)."""
        return max(1, -(-self.samples // self.pass_samples))

    def chunk_size(self, n: int) -> int:
        """Texels per fixed chunk of an atlas of `n` bake points: `chunk_texels` if set, else
        CHUNK_TEXELS, or for an atlas of fewer than MIN_CHUNKS such chunks an n / MIN_CHUNKS-th
        (at least MIN_CHUNK_TEXELS): a small atlas's passes, one unit per chunk, still spread
        over the cores. A function of n and the settings alone, so the bake does not depend on
        the threads (nor a farm's on its workers)."""
        if self.chunk_texels > 0:
            return self.chunk_texels
        return min(CHUNK_TEXELS, max(MIN_CHUNK_TEXELS, -(-n // MIN_CHUNKS)))

    @property
    def worker_threads(self) -> int:
        """The worker threads `threads` stands for (`parallel.resolve_threads`: 0 = every core this
        process may use). Raises BakeError for a negative count."""
        return parallel.resolve_threads(self.threads)

    def resolved(self) -> BakeSettings:
        """These settings with `threads` resolved (`worker_threads`), as a bake records them."""
        return replace(self, threads=self.worker_threads)


#: Passes a texel takes before its pass-to-pass spread may stop it (the spread of few passes is
#: noisy itself: from 4 Gaussian passes it lies between 0.34× and 1.6× the true error 90% of the
#: time, from 2 passes between 0.06× and 2×).
MIN_ADAPTIVE_PASSES = 4
#: Fraction of the atlas mean I_z below which the noise target is absolute, not relative.
NOISE_FLOOR = 0.1
#: Texels per chunk (`BakeSettings.chunk_size`) of an atlas large enough ...
CHUNK_TEXELS = 8192
#: ... to be cut into at least this many; a smaller atlas is cut into this many ...
MIN_CHUNKS = 8
#: ... of at least this many texels (a unit's fixed cost outweighs a smaller one's rays).
MIN_CHUNK_TEXELS = 512
