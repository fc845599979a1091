"""The bake's one progress range, shared out among its stages. No bpy.

`Progress` turns what the stages report into one fraction and a status line with an ETA for the
caller's `progress(fraction, message)` (the console line, `core.console.ConsoleProgress`, and
Blender's progress bar, `operators/modal_work.py`). The fractions it passes on never go back,
and reach 1.0 only with `finish` (the files committed): before that they stop at LAST.

The range is shared out as the bake goes, never fixed in advance: a stage starting takes
(1 − where the bar is) × its estimated cost / the estimated cost of all the work not yet started
(`Progress.span`), so a stage that ends early (a trace stopped by its noise target) or late does
not make the bar jump or go back: what is left is shared again. The costs are estimates in
microseconds on this project's 2-core test machine (the `COST_*` constants): only their ratios
matter, and they scale with what each stage works on (baked texels, atlas texels, samples).

A stage gets a `Tick`: calling it checks for cancellation (raises BakeCancelled), as the
`check()` every stage takes always did, so a Tick is passed where a `check` goes; `tick.at(f,
message)` also reports `f` of the way through the stage, and `tick.split(weights)` cuts it into
consecutive parts. A stage given a plain `check` (a re-encode, a farm worker, a test) gets a
Tick that reports nothing (`ticker`). Reporting costs a few microseconds: stages report per
denoiser band, stitch iteration, encode chunk and band of written rows, never per texel.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

#: The highest fraction reported before `finish`: 100% only once the files are committed.
LAST = 0.999

# Estimated cost per unit of work, in microseconds on the 2-core test machine (only the ratios
# matter), from the stages of two 4096² Production bakes of bench/end_to_end.py: the bedroom
# (7.0M texels baked, 449k triangles) and three bedrooms side by side (2.4M texels, 1.35M
# triangles, 19,863 charts). Where the two differ (stitching and encoding grow with the seams),
# the constant lies between them.
#: Checking for faces that point in (`core.bakepoints.inward`), per receiver triangle.
COST_INWARD = 1.5
#: The bake points of one atlas texel (raster, probes): per baked texel.
COST_POINTS = 3.0
#: Tracing one sample of one texel, per bounce after the first hit added: × (1 + bounces / 2).
COST_SAMPLE = 0.33
#: Finding the seams (per baked texel).
COST_SEAMS = 1.2
#: The texel images of a traced atlas (per baked texel).
COST_IMAGE = 0.3
#: Writing one channel of one texel of a raw EXR (float, ZIP; per texel of the window written).
COST_WRITE = 0.004
#: Writing one channel of one texel of an encoded EXR or of a preview image made of it.
COST_WRITE_ENCODED = 0.018
#: The denoiser (per baked texel).
COST_DENOISE = 14.0
#: Seam stitching of the SH and of the encoded layers (per baked texel).
COST_STITCH = 6.0
#: Encoding (HHD's fit) and filling the layers (per baked texel).
COST_ENCODE = 1.0
#: The post stages' costs by name (`core.post.stages_for`; the stitch stage's SH half: the
#: other, `post.stitch_encoded`, runs after encoding).
POST_COSTS = {"denoise": COST_DENOISE, "stitch": 0.6 * COST_STITCH}
#: Tracing one probe (a full sphere), per sample and bounce as COST_SAMPLE.
COST_PROBE = 0.6


class Progress:
    """Stage progress → one monotone fraction plus a status line with the ETA, for `callback(fraction,
    message)` (None: nothing is reported, the spans still work). `cancel()` True → the Ticks of
    `span` raise BakeCancelled. `left`: the estimated cost of all the work (`plan`)."""

    def __init__(self, callback: Callable[[float, str], None] | None, cancel: Callable[[], bool] | None = None):
        self.callback, self.cancel = callback, cancel
        self.start = time.perf_counter()
        self.shown = 0.0
        self.left = 0.0
        self._lock = threading.Lock()

    def plan(self, cost: float) -> None:
        """Add `cost` to the estimated cost of the work not yet started."""
        self.left += max(cost, 0.0)

    def span(self, cost: float, name: str = "") -> Tick:
        """A Tick over the next part of the range for a stage of estimated `cost` (which `plan`
        counted): its share of what is left of the range, as its cost is of the work left."""
        cost = max(cost, 0.0)
        lo = self.shown
        share = cost / self.left if self.left > cost else 1.0
        self.left = max(self.left - cost, 0.0)
        return Tick(self.report, lo, lo + (1.0 - lo) * share, self.check, name)

    def check(self) -> None:
        if self.cancel is not None and self.cancel():
            from .errors import BakeCancelled

            raise BakeCancelled("bake cancelled")

    def report(self, fraction: float, message: str) -> None:
        """Report `fraction` of the whole bake (held at where it was if lower, at most LAST)."""
        with self._lock:
            fraction = min(max(fraction, self.shown), LAST)
            self.shown = fraction
            if self.callback is None:
                return
            elapsed = time.perf_counter() - self.start
            eta = elapsed / fraction * (1.0 - fraction) if fraction > 0.02 else None
            tail = f", ETA {format_seconds(eta)}" if eta is not None else ""
            self.callback(fraction, f"{message}{tail}")

    def finish(self, message: str) -> None:
        """The bake is done (its files committed): 1.0."""
        with self._lock:
            self.shown = 1.0
            if self.callback is not None:
                self.callback(1.0, f"{message} in {format_seconds(time.perf_counter() - self.start)}")


def with_eta(callback: Callable[[float, str], None]) -> Callable[[float, str], None]:
    """`callback(fraction, message)` of a job outside a bake's `Progress` (an unwrap) with the
    ETA that `Progress.report` adds: from the time since the first call, once past 2%."""
    start = time.perf_counter()

    def report(fraction: float, message: str) -> None:
        elapsed = time.perf_counter() - start
        eta = elapsed / fraction * (1.0 - fraction) if 0.02 < fraction < 1.0 else None
        callback(fraction, f"{message}, ETA {format_seconds(eta)}" if eta is not None else message)

    return report


def format_seconds(s: float) -> str:
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.1f} min"


class Tick:
    """One stage's part [lo, hi] of the bake's range. `tick()` raises to cancel (the stage's
    `check`); `tick.at(f, message)` reports f ∈ [0, 1] of the stage done (then checks);
    `split` cuts it into consecutive parts. `name` heads its messages (e.g. "denoise 'Lightmap'")."""

    def __init__(
        self,
        report: Callable[[float, str], None] | None,
        lo: float = 0.0,
        hi: float = 1.0,
        check: Callable[[], None] | None = None,
        name: str = "",
    ):
        self.report, self.lo, self.hi, self.check, self.name = report, lo, hi, check, name

    def __call__(self) -> None:
        if self.check is not None:
            self.check()

    @property
    def reports(self) -> bool:
        """Whether `at` reports anything (a stage may skip building a message otherwise)."""
        return self.report is not None

    def at(self, fraction: float, message: str = "") -> None:
        self.show(fraction, message)
        self()

    def show(self, fraction: float, message: str = "") -> None:
        """`at` without the cancel check (for a stage that checks on its own, the tracer)."""
        if self.report is not None:
            f = min(max(fraction, 0.0), 1.0)
            text = f"{self.name}: {message}" if self.name and message else self.name or message
            self.report(self.lo + (self.hi - self.lo) * f, text)

    def part(self, a: float, b: float, name: str | None = None) -> Tick:
        """The part from `a` to `b` (fractions of this one)."""
        span = self.hi - self.lo
        return Tick(
            self.report, self.lo + span * a, self.lo + span * b, self.check, self.name if name is None else name
        )

    def split(self, weights: Sequence[float], names: Sequence[str | None] | None = None) -> list[Tick]:
        """Consecutive parts in proportion to `weights` (names: each part's, None keeps this one's)."""
        total = float(sum(max(w, 0.0) for w in weights)) or 1.0
        out, a = [], 0.0
        for k, w in enumerate(weights):
            b = a + max(w, 0.0) / total
            out.append(self.part(a, min(b, 1.0), None if names is None else names[k]))
            a = b
        return out

    def counter(self, total: int, message: Callable[[int, int], str]) -> Callable[[int], None]:
        """`step(done)`: reports done / total with `message(done, total)` (built only when reported)."""
        total = max(total, 1)

        def step(done: int) -> None:
            self.at(done / total, message(done, total) if self.report is not None else "")

        return step


def ticker(check: Callable[[], None] | None) -> Tick:
    """`check` as a Tick: itself if it is one, else a Tick that checks with it and reports nothing."""
    if isinstance(check, Tick):
        return check
    return Tick(None, check=check)
