"""The farm's client: `connect` checks every worker, `Farm` submits, collects, checkpoints and
finishes each atlas's tasks (the package's docstring has the design). No bpy."""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import socket
import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import BakeCancelled, BakeError, DependencyMissing
from ..tracer import scheduler
from ..tracer.scheduler import Outcome
from ..tracer.settings import MIN_ADAPTIVE_PASSES, BakeSettings
from ..tracer.statistics import Statistics
from . import finishing as finishing_tasks
from . import worker as worker_tasks
from .finishing import STATISTICS, denoiser_identity
from .names import PACKAGE, WORKER_PACKAGE, _Named, dumps, ship, unplain
from .worker import MATCHED, code_fingerprint, environment

#: The hidden folder of the output folder holding finished tasks' checkpoints.
CHECKPOINTS = ".hhd_farm"


#: Fixed chunks per task (`BakeSettings.chunk_texels` texels each): long enough to hide a task's
#: overhead at usual sample counts (bench/results/farm.md has the per-task costs).
CHUNKS_PER_TASK = 4


#: Times the client submits a task again after it failed on the farm (beyond Dask's own
#: rescheduling of a task whose worker died), before the bake fails.
RETRIES = 2


#: How often the client looks for finished tasks and a cancel.
POLL_SECONDS = 0.05


INSTALL_HINT = (
    "install Dask into the Python that runs the bake: `pip install \"dask[distributed]\"` "
    "(with Blender: `blender -b --python-expr \"import subprocess, sys; subprocess.check_call([sys.executable, "
    "'-m', 'pip', 'install', 'dask[distributed]'])\"`; docs/farm.md)"
)


def _probe(address: str, timeout: float) -> None:
    """BakeError at once when a tcp:// scheduler address cannot be reached because nothing
    listens there or the host is unknown: Dask's client would retry until its `timeout`. Any
    other outcome (it answers, or does not answer in time) is left to the client."""
    scheme, sep, rest = address.rpartition("://")
    host, colon, port = rest.rpartition(":")
    if (sep and scheme != "tcp") or not colon:
        return  # another protocol, or Dask's default port
    try:
        with socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout=min(timeout, 5.0)):
            return
    except ValueError:
        raise BakeError(f"cannot reach the Dask scheduler at {address}: expected tcp://HOST:PORT") from None
    except (ConnectionRefusedError, socket.gaierror) as exc:
        raise BakeError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    except OSError:
        return


def connect(address: str, chunks_per_task: int = CHUNKS_PER_TASK, timeout: float = 30.0) -> Farm:
    """A Farm on the Dask scheduler at `address` (e.g. tcp://host:8786), after checking that at
    least one worker is there and every worker's `environment()` matches this process's (else
    BakeError naming what differs). DependencyMissing when Dask is not installed here."""
    try:
        import distributed
    except ImportError:
        if PACKAGE == WORKER_PACKAGE:  # the package as pip installs it
            raise DependencyMissing(f"--scheduler needs Dask, which this Python lacks: {INSTALL_HINT}") from None
        raise DependencyMissing(  # the extension, which bundles Dask's wheels
            "--scheduler needs Dask, which the extension bundles as wheels, but Blender's Python cannot import it: "
            "reinstall the extension from the zip for this platform (Blender installs an extension's wheels when it "
            f"enables it; 4.2.13 or newer), or {INSTALL_HINT}"
        ) from None
    _probe(address, timeout)
    try:
        client = distributed.Client(address, timeout=timeout, set_as_default=False)
    except ValueError as exc:  # a malformed address (the CLI refuses those before; a scene setting may hold one)
        raise BakeError(f"'{address}' is not a Dask scheduler address ({exc}): give tcp://HOST:PORT") from None
    except (OSError, TimeoutError) as exc:
        raise BakeError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            raise BakeError(f"the Dask scheduler at {address} has no worker (start `dask worker {address}`)") from None
        farm = Farm(client, address, chunks_per_task)
        farm.warnings = check_workers(client.run(_Named(worker_tasks.__name__, "environment"), on_error="return"))
        return farm
    except BaseException:
        client.close()
        raise


def check_workers(envs: dict) -> list[str]:
    """BakeError if a worker cannot run the bake or runs other code or package versions than this
    process; returns warnings (workers of other CPU targets: see docs/farm.md)."""
    mine = environment()
    problems: list[str] = []
    cpus: dict[tuple, list[str]] = {}
    for worker, env in sorted(envs.items()):
        if isinstance(env, BaseException):
            hint = (
                f" (install it on the workers: pip install \"{WORKER_PACKAGE}[farm]\")"
                if isinstance(env, ImportError)
                else ""
            )
            problems.append(f"{worker}: {type(env).__name__}: {env}{hint}")
            continue
        differ = [f"{k} {env.get(k)} (here {mine[k]})" for k in ("code", "python", *MATCHED) if env.get(k) != mine[k]]
        if differ:
            problems.append(f"{worker}: {', '.join(differ)}")
        cpus.setdefault((env.get("cpu"), env.get("embree_config"), env.get("machine")), []).append(worker)
    if problems:
        raise BakeError(
            "the farm's workers do not match this bake's versions (a farm bake is bit-identical to a local bake only "
            "with the same code and packages): " + "; ".join(problems)
        )
    if len(cpus) > 1:
        kinds = "; ".join(f"cpu {c}, Embree '{e}', {m}: {len(w)} worker(s)" for (c, e, m), w in cpus.items())
        return [
            f"the farm's workers are of {len(cpus)} CPU kinds ({kinds}): results may differ in the last bits "
            "between them; pin NUMBA_CPU_NAME and HHD_EMBREE_CONFIG on every worker (docs/farm.md)"
        ]
    return []


class Finishing:
    """One atlas's finishing task on the farm (`Farm.finish`): its name, its tracing's plan
    (without the estimator's bytes), the task's arguments, the workers it should run on (none:
    any), its future; `estimator`: to ship again for a retry."""

    def __init__(self, name: str, plan: dict, args: tuple, workers: list[str], estimator):
        self.name, self.args, self.workers, self.estimator = name, args, workers, estimator
        self.plan = {k: v for k, v in plan.items() if k not in ("payload", "data")}
        self.future: Any = None  # a distributed.Future once started
        self.retries = 0

    def done(self) -> bool:
        return self.future is not None and self.future.done()


class Farm:
    """A connected Dask client: `submit` starts an atlas's tracing, `finish` its finishing task
    (`result` waits for it); `runner(name, out_dir)` traces one atlas alone (tests, benches)."""

    def __init__(self, client, address: str, chunks_per_task: int = CHUNKS_PER_TASK):
        if chunks_per_task < 1:
            raise BakeError(f"chunks per task must be ≥ 1, got {chunks_per_task}")
        self.client, self.address, self.chunks_per_task = client, address, chunks_per_task
        self.warnings: list[str] = []
        self.checkpoints: list[Path] = []
        self.tasks: list[dict] = []  # per finished task: seconds, worker, texels (bench/farm.py)
        self._submitted: dict[str, dict] = {}  # checkpoint key -> {future: group} started by `submit`
        self._points: list = []  # the futures of `bake_points`
        self._finishing: list[Finishing] = []  # finishing tasks not collected yet
        self._oidn: dict[str, list[str]] = {}  # the client's denoiser identity -> workers of the same
        self.finishing: list[dict] = []  # per finished atlas: seconds, worker, finished_on (bench/farm.py)

    def __enter__(self) -> Farm:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.cancel_all()
        self.client.close()

    def workers(self) -> int:
        return len(self.client.scheduler_info(n_workers=-1)["workers"])

    @staticmethod
    def check(settings: BakeSettings) -> None:
        """BakeError for settings a farm cannot bake reproducibly (a time budget)."""
        if settings.time_budget:
            raise BakeError(
                "a time budget cannot be used with --scheduler: where it stops depends on the farm's speed, so the "
                "result would not be reproducible; use --samples or --noise-target instead"
            )

    def runner(self, name: str, out_dir) -> Callable[..., Outcome]:
        """A stand-in for `tracer.scheduler.run` tracing atlas `name` on the farm, its finished
        tasks checkpointed under `out_dir`/.hhd_farm."""

        def run(estimator, stats, settings, start, progress=None, cancel=None, executor=None) -> Outcome:
            return self._trace(name, Path(out_dir), estimator, stats, settings, start, progress, cancel)

        return run

    def finished(self) -> None:
        """The bake's files are committed: delete its checkpoints."""
        for folder in self.checkpoints:
            shutil.rmtree(folder, ignore_errors=True)
        for folder in {f.parent for f in self.checkpoints}:
            try:
                folder.rmdir()  # only when empty (another bake's may be there)
            except OSError:
                pass
        self.checkpoints = []

    def bake_points(self, atlases, scene, cancel: Callable[[], bool] | None = None) -> list[Callable[[], object]]:
        """Start the bake points of every atlas (`core.bake.AtlasInput`) on the farm, against
        `scene` (BakeScene); returns per atlas a function waiting for its BakePoints (the same
        as `bakepoints.build` here; BakeCancelled when `cancel()` turns True meanwhile). The scene
        is sent once, to every worker."""
        payload = dumps(scene)
        digest = hashlib.blake2b(payload, digest_size=16).hexdigest()
        [data] = self.client.scatter([payload], hash=True, broadcast=True)
        task = _Named(worker_tasks.__name__, "points_task")
        futures = [
            self.client.submit(task, data, digest, dumps((a.surface, a.width, a.height)), pure=False) for a in atlases
        ]
        self._points = futures
        return [functools.partial(self._wait_points, f, a.name, cancel) for f, a in zip(futures, atlases)]

    def _wait_points(self, future, name: str, cancel) -> object:
        while not future.done():
            if cancel is not None and cancel():
                self.cancel_all()
                raise BakeCancelled("bake cancelled")
            time.sleep(POLL_SECONDS)
        try:
            result = future.result()
        except BakeError:
            raise
        except Exception as exc:  # the worker's error, KilledWorker
            raise BakeError(
                f"the bake points of atlas '{name}' failed on the farm: {type(exc).__name__}: {exc}"
            ) from exc
        future.release()
        return unplain(result)

    def submit(self, name: str, out_dir, estimator, settings: BakeSettings) -> None:
        """Start tracing atlas `name` now (its first stage's tasks not checkpointed yet), so the
        farm works on every atlas while the client collects and writes one after the other
        (`bake.run` submits them all after the bake points). `finish` (or `tracer.bake(...,
        runner=)`) with the same estimator and settings then picks these tasks up."""
        plan = self._plan(name, Path(out_dir), estimator, settings)
        if plan["key"] not in self._submitted:
            self._submitted[plan["key"]] = self._submit(plan, 0, None, self._saved(plan, 0))

    def _plan(self, name: str, out_dir: Path, estimator, settings: BakeSettings) -> dict:
        """What the tasks of one atlas need: its chunk groups, stages, the estimator's bytes and
        the key of its checkpoints."""
        self.check(settings)
        n = len(estimator.points.texel)
        chunks = [(c, int(a[0]), int(a[-1]) + 1) for c, a in enumerate(scheduler.chunks(settings, n))]
        groups = [chunks[g : g + self.chunks_per_task] for g in range(0, len(chunks), self.chunks_per_task)]
        digest, payload = ship(estimator)
        trace = {k: v for k, v in asdict(settings).items() if k != "threads"}
        code = code_fingerprint()
        key = hashlib.blake2b(
            repr((name, digest, sorted(trace.items()), self.chunks_per_task, code)).encode(), digest_size=10
        ).hexdigest()
        passes = settings.passes
        two_stages = bool(settings.noise_target) and passes >= MIN_ADAPTIVE_PASSES
        return {
            "name": name,
            "key": key,
            "folder": out_dir / CHECKPOINTS / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', name)}-{key}",
            "groups": groups,
            "digest": digest,
            "payload": payload,
            "trace": trace,
            "code": code,
            "stages": [(0, MIN_ADAPTIVE_PASSES), (MIN_ADAPTIVE_PASSES, passes)] if two_stages else [(0, passes)],
        }

    def _saved(self, plan: dict, stage: int) -> dict[int, dict]:
        """The checkpointed results of one stage, by group."""
        saved = {}
        for g in range(len(plan["groups"])):
            result = _load(plan["folder"] / f"task-{g}-{stage}.npz")
            if result is not None:
                saved[g] = result
        return saved

    def _submit(self, plan: dict, stage: int, floor: float | None, saved: dict, only=None) -> dict:
        """Submit the tasks of one stage that no checkpoint holds (of the groups `only`, if
        given): {future: group}."""
        pending = {}
        todo = [g for g in (range(len(plan["groups"])) if only is None else only) if g not in saved]
        if todo:
            if "data" not in plan:
                # content-keyed, copied to every worker: a dying worker does not take the only copy
                [plan["data"]] = self.client.scatter([plan["payload"]], hash=True, broadcast=True)
            task = _Named(worker_tasks.__name__, "trace_group")
            for g in todo:
                state = _load(plan["folder"] / f"task-{g}-0.npz") if stage == 1 else None
                future = self.client.submit(
                    task,
                    plan["data"],
                    plan["digest"],
                    plan["trace"],
                    plan["code"],
                    plan["groups"][g],
                    plan["stages"][stage],
                    state,
                    floor,
                    key=f"hhd-{plan['key']}-{stage}-{g}-{uuid.uuid4().hex[:8]}",  # unique: a cancelled one may linger
                    pure=False,
                )
                pending[future] = g
        return pending

    def _trace(self, name, out_dir: Path, estimator, stats: Statistics, settings, start, progress, cancel) -> Outcome:
        plan = self._plan(name, out_dir, estimator, settings)
        rays, stopped_by, _ = self._collect(plan, stats, settings, start, progress, cancel)
        plan.pop("data", None)
        return Outcome(stopped_by, rays)

    def _collect(
        self, plan: dict, stats, settings: BakeSettings, start: float, progress, cancel, keep: bool = False
    ) -> tuple[int, str, dict]:
        """Run (or load from checkpoints) every task of one atlas, checkpointing each as it
        finishes and copying its arrays into `stats` (those of STATISTICS it has: a finishing
        bake keeps only what the noise target's floor needs). Returns the rays traced, what
        stopped the bake, and with `keep` the last stage's result per group (its future, kept
        on the farm for the finishing task, or a checkpoint's arrays)."""
        folder, groups = plan["folder"], plan["groups"]
        folder.mkdir(parents=True, exist_ok=True)
        if folder not in self.checkpoints:
            self.checkpoints.append(folder)
        rays, converged, done = 0, True, 0
        of = len(groups) * len(plan["stages"])
        last = len(plan["stages"]) - 1
        final: dict = {}

        def add(g: int, result, stage: int) -> None:
            nonlocal rays, converged, done
            first, end = int(result["first"]), int(result["end"])
            for k in STATISTICS:
                if getattr(stats, k, None) is not None:
                    getattr(stats, k)[first:end] = result[k]
            stats.texel_passes += int(result["texel_passes"])
            rays += int(result["rays"])
            if stage == last:
                converged &= bool(result["converged"])
            done += 1
            if progress:
                elapsed = max(time.perf_counter() - start, 1e-9)
                progress(
                    done / of,
                    f"farm: {done} of {of} tasks, {rays / elapsed / 1e6:.2f} M rays/s, "
                    f"{stats.texel_passes * settings.pass_samples / elapsed / 1e3:.0f} k texel-samples/s",
                )

        retries: dict[int, int] = {}
        for s in range(len(plan["stages"])):
            floor = stats.floor() if s == 1 else None  # the atlas's, after the first stage (scheduler.py)
            saved = self._saved(plan, s)
            for g, result in saved.items():
                add(g, result, s)
                if keep and s == last:
                    final[g] = result
            submitted = self._submitted.pop(plan["key"], None) if s == 0 else None
            if submitted is not None:  # `submit` started them: drop those a checkpoint now holds
                pending = {f: g for f, g in submitted.items() if g not in saved}
                self.client.cancel([f for f, g in submitted.items() if g in saved])
            else:
                pending = self._submit(plan, s, floor, saved)
            try:
                while pending:
                    finished = [f for f in pending if f.done()]
                    if not finished:
                        time.sleep(POLL_SECONDS)
                    for future in [*finished, None]:
                        if cancel is not None and cancel():
                            raise BakeCancelled("bake cancelled")
                        if future is None:
                            break
                        g = pending.pop(future)
                        try:
                            result = future.result()
                        except BakeError:
                            raise
                        except Exception as exc:  # KilledWorker, a worker's error, lost data, a cancel on the farm
                            retries[g] = retries.get(g, 0) + 1
                            if retries[g] > RETRIES:
                                raise BakeError(
                                    f"farm task {g} of atlas '{plan['name']}' failed: {type(exc).__name__}: {exc}"
                                ) from exc
                            plan.pop("data", None)  # scattered again: its copies may be what was lost
                            pending.update(self._submit(plan, s, floor, {}, only=[g]))
                            continue
                        _save(folder / f"task-{g}-{s}.npz", result)
                        self.tasks.append(
                            {
                                "seconds": float(result["seconds"]),
                                "worker": result["worker"],
                                "texels": len(result["iz"]),
                            }
                        )
                        add(g, result, s)
                        if keep and s == last:
                            final[g] = future  # its data stays on the farm for the finishing task
                        else:
                            future.release()
            except BaseException:
                self.cancel_all()
                raise
            finally:
                if pending:  # cancelled or failed: no task of this bake keeps running on the farm
                    self.client.cancel(list(pending), force=True)
        two_stages = len(plan["stages"]) == 2
        stopped = "noise_target" if two_stages and converged and len(stats.passes) else "samples"
        return rays, stopped, final

    # ---- finishing on the farm: post stages and encoding per atlas ----------------------------

    def finish(
        self, atlas, settings, out_dir, estimator, t_points: float, extra: dict, progress=None, cancel=None
    ) -> Finishing:
        """Collect the tracing of `atlas` (`core.bake.AtlasInput`; started by `submit`, or
        started now) with `estimator` (as `submit`'s), then start its finishing task
        (`finish_task`: post stages and encoding on a worker, ahead of queued tracing tasks);
        returns at once with its handle (`result` waits). `settings`: the PipelineSettings;
        `t_points`, `extra`: the sidecar's bake-point seconds and extra entries."""
        start = time.perf_counter()
        plan = self._plan(atlas.name, Path(out_dir), estimator, settings.trace)
        n = len(estimator.points.texel)
        floor_stats = Statistics.__new__(Statistics)  # only what the noise target's floor reads
        floor_stats.iz, floor_stats.passes, floor_stats.texel_passes = np.zeros(n), np.zeros(n, np.int64), 0
        rays, stopped_by, final = self._collect(plan, floor_stats, settings.trace, start, progress, cancel, keep=True)
        saved = {g: r for g, r in final.items() if isinstance(r, dict)}
        if saved:  # checkpointed results travel to the farm as data
            for g, future in zip(saved, self.client.scatter(list(saved.values()))):
                final[g] = future
        if "data" not in plan:
            [plan["data"]] = self.client.scatter([plan["payload"]], hash=True, broadcast=True)
        identity = denoiser_identity(settings.denoiser_library) if settings.denoise else None
        meta = dumps(
            {
                "atlas": replace(atlas, surface=None),
                "settings": settings,
                "t_points": t_points,
                "extra": extra,
                "rays": rays,
                "stopped_by": stopped_by,
                "seconds": time.perf_counter() - start,
                "denoiser": identity,
            }
        )
        args = (plan["data"], plan["digest"], plan["code"], meta, *[final[g] for g in range(len(plan["groups"]))])
        workers = self._denoisers(identity) if identity is not None else []
        handle = Finishing(atlas.name, plan, args, workers, estimator)
        self._start(handle)
        return handle

    def _reload(self, handle: Finishing) -> None:
        """The arguments of a failed finishing task made anew from what cannot be lost: the
        estimator shipped again and the tracing results from their checkpoints (a dead worker may
        have held the only copy of either: Dask keeps one replica of scattered data)."""
        plan = handle.plan
        last = len(plan["stages"]) - 1
        results = [_load(plan["folder"] / f"task-{g}-{last}.npz") for g in range(len(plan["groups"]))]
        if any(r is None for r in results):
            raise BakeError(f"the checkpoints of atlas '{handle.name}' are gone from {plan['folder']}: bake again")
        _, payload = ship(handle.estimator)
        [data] = self.client.scatter([payload], hash=True, broadcast=True)
        handle.args = (data, *handle.args[1:4], *self.client.scatter(results))

    def _denoisers(self, identity: str) -> list[str]:
        """The workers whose OIDN is the client's (`denoiser_identity` `identity`), asked once
        per farm: the finishing tasks of a denoised bake go to them first."""
        if identity not in self._oidn:
            found = self.client.run(_Named(finishing_tasks.__name__, "local_denoiser"), on_error="return")
            self._oidn[identity] = sorted(
                w for w, r in found.items() if not isinstance(r, BaseException) and r[1] == identity
            )
        return self._oidn[identity]

    def _start(self, handle: Finishing) -> None:
        """Submit (again) the finishing task of `handle`."""
        handle.future = self.client.submit(
            _Named(finishing_tasks.__name__, "finish_task"),
            *handle.args,
            key=f"hhd-finish-{handle.plan['key']}-{uuid.uuid4().hex[:8]}",
            pure=False,
            priority=1,  # before the tracing tasks still queued: the client writes sooner
            workers=handle.workers or None,
            allow_other_workers=bool(handle.workers),  # another worker if none of them is left
        )
        self._finishing.append(handle)

    def result(self, handle: Finishing, cancel=None) -> tuple[str, object]:
        """Wait for the finishing task of `handle`: ("out", {"out": the files to stage in order
        [(method of `bake.finishing.Staged`, args)], "summary": `bake.finishing.finish_atlas`'s}) or
        ("traced", a TracedAtlas without points: this client must finish it, `finish_task`). BakeCancelled
        when `cancel()` turns True; a failed task is submitted again RETRIES times."""
        try:
            while True:
                while True:  # a cancel is seen before an answer is taken, even one already there
                    if cancel is not None and cancel():
                        raise BakeCancelled("bake cancelled")
                    if handle.future.done():
                        break
                    time.sleep(POLL_SECONDS)
                try:
                    answer = handle.future.result()
                    break
                except BakeError:
                    raise
                except Exception as exc:  # KilledWorker, a worker's error, lost inputs
                    handle.retries += 1
                    if handle.retries > RETRIES:
                        raise BakeError(
                            f"the finishing task of atlas '{handle.name}' failed on the farm: {type(exc).__name__}: {exc}"
                        ) from exc
                    self._finishing.remove(handle)
                    self._reload(handle)
                    self._start(handle)
        except BaseException:
            self.cancel_all()
            raise
        self._finishing.remove(handle)
        handle.future.release()
        handle.args, handle.estimator = (), None  # the tracing results and the estimator may go from the farm
        record = {"atlas": handle.name, "seconds": float(answer["seconds"]), "worker": answer["worker"]}
        where = "client" if "traced" in answer else "worker"
        self.finishing.append({**record, "finished_on": where, "bytes": _nbytes(answer)})
        if "traced" in answer:
            return "traced", unplain(answer["traced"])
        return "out", {"out": unplain(answer["out"]), "summary": unplain(answer["summary"])}

    def cancel_all(self) -> None:
        """Cancel the tasks `submit` and `bake_points` started that were not collected yet."""
        for submitted in self._submitted.values():
            self.client.cancel(list(submitted), force=True)
        self._submitted.clear()
        if self._points:
            self.client.cancel(self._points, force=True)
            self._points = []
        if self._finishing:
            self.client.cancel([h.future for h in self._finishing], force=True)
            self._finishing = []


def _nbytes(obj) -> int:
    """Bytes of the arrays in `obj` (nested dicts, lists, tuples): what a task's answer carried."""
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, dict):
        return sum(_nbytes(v) for v in obj.values())
    if isinstance(obj, list | tuple):
        return sum(_nbytes(v) for v in obj)
    return 0


def _save(path: Path, result: dict) -> None:
    tmp = path.with_suffix(".tmp.npz")
    arrays: dict = {k: np.asarray(v) for k, v in result.items() if k != "worker"}
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _load(path: Path) -> dict | None:
    """A checkpoint's arrays, or None if missing or unreadable (then the task runs again)."""
    if not path.exists():
        return None
    try:
        with np.load(path) as f:
            return {k: f[k] for k in f.files}
    except (OSError, ValueError, KeyError):
        path.unlink(missing_ok=True)
        return None
