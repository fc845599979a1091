"""The bake on a Dask cluster (a render farm), bit-identical to the local bake. No bpy.

`connect(address)` opens a `dask.distributed` client (imported here only: a bake without a
scheduler never imports Dask) and checks that every worker runs the same tracer code and the
same compiled packages as this process. `bake.run(..., farm=)` then traces every atlas as Dask
tasks, one per group of `chunks_per_task` fixed chunks of `BakeSettings.chunk_texels` texels,
each task running *every pass* of its chunks, and finishes each atlas in one more task
(`Farm.submit`, `Farm.finish`, below).

Bit-identical. A local bake adds, pass after pass, each chunk's estimate to per-texel running
statistics (`Statistics.add`, Welford per texel), and a chunk's estimate depends only on
(seed, pass, chunk index, its texels) (`WorkUnit`). A texel's statistics therefore depend only
on its own estimates in pass order, which a task reproduces by running the passes of its chunks
in order into statistics of its own; the client copies them into the atlas's statistics. The
result does not depend on the number of workers, the group size, retries, duplicates or the
order tasks finish in. The noise target's rule is the local scheduler's (`scheduler.py`): chunks
stay fixed, and the floor is fixed once from the atlas after MIN_ADAPTIVE_PASSES passes; so with
a noise target each group takes two tasks, the first MIN_ADAPTIVE_PASSES passes, then, with the
floor the client computed from all of them, the rest. A time budget is refused (`Farm.check`):
where it stops would depend on the farm's speed.

Shipping. The estimator (bake points, scene, lights; `tracer.shipping.Shipped`) is pickled once
per atlas, with this package's module names rewritten to the worker's `hhd_lightmapper` (inside
Blender the extension is `bl_ext.<repo>.hhd_lightmapper`), scattered to the cluster under a key
made from its content hash, fetched once per worker and unpickled once per worker process
(`shipping._receive`), where its Embree scenes are rebuilt once per triangle content
(`shipping.ray_scene`) and the compiled kernels load from numba's disk cache (`core.compiled`).

Bake points. `Farm.bake_points` runs `bakepoints.build` of every atlas as one task each, against
the BakeScene sent once to every worker; the BakePoints come back as plain data (`plain`,
`unplain`) and equal the local ones. They are not checkpointed (a restart builds them again).

Every atlas's tracing tasks start at once (`Farm.submit`, called by `bake.run`'s runner,
`bake.runners.FarmRunner`, after the bake points); the runner then collects them atlas by atlas
(`Farm.finish`) and starts each atlas's finishing task
(`finish_task`) once its tracing is done: on a worker, with the tracing results Dask moves there,
it reduces the statistics group by group to what the files take, builds the (compact)
TracedAtlas and runs `bake.finishing.finish_atlas` (seams, post stages, encoding), returning the encoded images and sidecars as plain data (`plain`); the client
only writes them (`bake.finishing.Staged`), so the farm traces and finishes the next atlases meanwhile. The
denoiser runs on a worker only with the client's own OIDN files (`denoiser_identity`,
`local_denoiser`); a task without them returns the TracedAtlas and the client finishes that atlas.
`Farm.runner` traces one atlas for `tracer.bake(..., runner=)` (tests, benches).

Nothing lost. A worker killed mid-task costs a retry of its task (Dask reschedules it; the
client resubmits a failed task RETRIES times; a failed finishing task with its inputs made anew
from the checkpoints). Each finished task's statistics are written to
`<out_dir>/.hhd_farm/<atlas>-<key>/` (key: a hash of the atlas's name, the estimator's bytes, the
tracer settings, the grouping and the code), so the same command run again resumes from them;
`Farm.finished()` deletes them once the bake's files are committed. `cancel()` (Ctrl-C on the
command line) cancels the farm's tasks and raises BakeCancelled. docs/farm.md is the user's side.
"""

from .client import Farm, connect

__all__ = ["Farm", "connect"]
