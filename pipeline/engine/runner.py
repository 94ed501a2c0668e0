"""The stage runner: runs the (scene, stage) pairs :mod:`pipeline.engine.stagegraph` plans, one unit of work for the
serial path and every dask scheduler, with atomic publication.

A stage is a pure function ``run(ctx: StageContext) -> dict`` (its summary figures). It reads its
inputs from ``ctx.inputs``, its typed config from ``ctx.config`` (built from params by the stage's
``Config``; exactly what its params digest covers), and writes exactly the paths in ``ctx.outputs``
(temporary locations); the runner digests and publishes them with the manifest. One unit of work,
:func:`run_stage`, serves the serial path and every dask scheduler; :func:`run_many` runs a plan on one.
"""

from __future__ import annotations

import os
import platform
import socket
import threading
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterator

from pipeline import __version__
from pipeline import logs
from pipeline.engine import codedeps
from pipeline.config import Params, RunParams
from pipeline.stageconfig import StageConfig, digest_value
from pipeline.errors import StageError, ZiponError, os_error_message
from pipeline.engine.manifest import Manifest, OutputRecord
from pipeline.paths import ARTIFACTS, Workspace
from pipeline.engine.locks import output_lock
from pipeline.engine.publication import check_inputs_unchanged, publish_outputs, recover
from pipeline.store import ArrayDigests, content_digest, new_tmp_dir, remove, sweep_tmp
from pipeline.engine.process import (counters_since, limit_native_threads, native_threads, peak_rss_mb, process_counters,
                              release_free_memory)
from pipeline.engine.stagegraph import (SOURCE, StageSpec, input_digests, source_key, source_paths, stage_code_digest,
                                 stage_levels, staleness, upstream_stages)


@dataclass
class StageContext:
    """Everything a stage may use. Outputs are temporary paths the runner publishes on success."""

    scene: str
    stage: str
    config: StageConfig
    runtime: RunParams  # devices, batch sizes, threads: never change an artifact, in no digest
    workspace: Workspace
    inputs: dict[str, Path]
    outputs: dict[str, Path]
    params_digest: str
    show_progress: bool = True
    messages: list[str] = field(default_factory=list)
    # CPU seconds and peak RSS of the stage's own tasks that ran in other worker processes (map_ordered)
    # and the time it waited for its turn to consume their results (_consuming_turn)
    elsewhere: dict[str, float] = field(default_factory=lambda: {"cpu_seconds": 0.0, "peak_rss_mb": 0.0,
                                                                 "waited_seconds": 0.0})
    known_digests: dict[str, ArrayDigests] = field(default_factory=dict)  # output -> its arrays' digests

    @classmethod
    def build(cls, spec: StageSpec, params: Params, scene: str, workspace: Workspace, inputs: dict[str, Path],
              outputs: dict[str, Path], *, show_progress: bool = True) -> "StageContext":
        """The context of ``spec`` for ``scene``: its config built from ``params`` and that config's digest."""
        config, projection = spec.build_config(params, scene)
        return cls(scene, spec.name, config, params.run, workspace, inputs, outputs, digest_value(projection),
                   show_progress)

    def array_digests(self, output: str) -> ArrayDigests:
        """The content digests of ``output``'s arrays, for its writer to keep as it writes them
        (:class:`pipeline.store.ArrayDigests`): the runner then digests that zarr store without reading it back."""
        return self.known_digests.setdefault(output, ArrayDigests())

    def log(self, message: str) -> None:
        """Keep ``message`` for the stage's outcome and log it (``zipon.stages``, info)."""
        self.messages.append(message)
        if self.show_progress:
            logs.ensure_configured()  # a dask worker process: nothing configured its logging
        logs.get_logger("stages").info("%s/%s: %s", self.scene, self.stage, message)

    def progress(self, iterable, total: int | None = None, description: str = ""):
        """Iterate with a progress bar (rich) when progress is shown."""
        if not self.show_progress:
            return iterable
        from rich.progress import track

        return track(iterable, total=total, description=f"{self.scene}/{self.stage} {description}".strip(),
                     console=_stderr_console(), transient=True)

    def map_ordered(self, fn: Callable[[Any], Any], items: list) -> Iterator[Any]:
        """``fn(item)`` for each item, yielded in item order, as tasks on the workers that run the stages
        (:func:`ordered_tasks`): within-stage parallelism, e.g. one long scene's map chunks. The tasks ask for
        ``run.encoder_resources`` (the map stages' chunks are its only callers: they run the encoders)."""
        return ordered_tasks(fn, items, name=f"{self.stage}-{self.scene}", threads=self.runtime.threads_per_worker,
                             usage=self.elsewhere, resources=self.runtime.encoder_resources or None)


def ordered_tasks(fn: Callable[[Any], Any], items: list, *, name: str, threads: int = 1,
                  usage: dict[str, float] | None = None, resources: dict[str, float] | None = None) -> Iterator[Any]:
    """Yield ``fn(item)`` for every item, in item order, running the calls on every dask worker when there is one.

    Inside a ``dask.distributed`` worker (``run.scheduler`` ``processes``, which starts a local cluster, or a
    ``tcp://`` scheduler) the calls become tasks of the same cluster, submitted from the running stage task with
    ``worker_client()``: that task secedes from its worker's thread pool while it waits, so every worker, its own
    included, runs them, and the caller consumes (folds) the results in order as they come. At most one call
    per worker thread plus one is in flight, so results waiting to be consumed stay bounded. A static dask graph
    cannot do this: the number of calls (e.g. chunks of a scene's frames) is known only once the upstream stage
    has run. Anywhere else (``sync``, ``threads``, or no dask at all) the calls run here, one after the other:
    the same function on the same items, so the same results.

    ``fn`` and ``items`` must pickle (module-level functions, ``functools.partial`` of them). An exception of a
    call is raised here, with its type, when its turn comes. ``usage`` (``cpu_seconds``, ``peak_rss_mb``) adds up
    the calls that ran in other processes (this process's own CPU time already counts the rest), so a stage's
    manifest counts every worker its tasks used.

    ``resources`` (dask worker resources, e.g. ``{"GPU": 1}``): the calls run only on workers that offer them
    (``dask worker --resources GPU=1``), one at a time per unit there; a cluster where no worker offers them is
    an error naming ``run.encoder_resources``, not a wait forever. Outside a cluster they are not needed.

    Memory: what a caller folds (a map's accumulators) grows with the results it consumes. On the local cluster
    of ``processes`` a worker holds one stage at a time, seceded or not (:data:`STAGE_SLOT`). On a cluster
    someone else started, a worker starts every ready stage while those already started wait, seceded; there at
    most as many callers as a worker process has threads consume results at a time (:func:`_consuming_slots`);
    the others wait for their turn seceded, holding no worker thread and no results, and their calls are not
    submitted yet.
    """
    client_context = _worker_client()
    if client_context is None:
        for item in items:
            yield fn(item)
        return
    import uuid
    from collections import deque

    with client_context as client, _consuming_turn(usage):
        window = _window(client, resources)
        token = uuid.uuid4().hex[:8]
        todo = iter(enumerate(items))
        pending: deque = deque()

        def submit() -> None:
            for i, item in todo:
                pending.append(client.submit(_ordered_call, fn, threads, item, key=f"{name}-{i}-{token}", pure=False,
                                             priority=CALL_PRIORITY, resources=resources))
                return

        for _ in range(window):
            submit()
        while pending:
            result, pid, cpu_s, rss_mb = pending.popleft().result()
            submit()
            if usage is not None and pid != os.getpid():
                usage["cpu_seconds"] = usage.get("cpu_seconds", 0.0) + cpu_s
                usage["peak_rss_mb"] = max(usage.get("peak_rss_mb", 0.0), rss_mb)
            yield result


def _window(client, resources: dict[str, float] | None) -> int:
    """Calls of :func:`ordered_tasks` kept in flight: one per worker thread that may run them, plus one."""
    if not resources:
        return sum(client.nthreads().values()) + 1
    workers = client.scheduler_info()["workers"].values()
    able = [w for w in workers if all(w.get("resources", {}).get(k, 0) >= n for k, n in resources.items())]
    if not able:
        raise ZiponError(f"run.encoder_resources {resources}: no dask worker offers them (start the encoder workers "
                         "with e.g. `dask worker SCHEDULER --resources GPU=1`, or set run.encoder_resources: {})")
    return sum(min(int(w.get("resources", {})[k] // n) for k, n in resources.items()) for w in able) + 1


# dask worker resource of our local cluster: one per worker process, asked for by every stage task (not by the
# calls of ordered_tasks). A map stage secedes while it waits for its chunks and folds them; a seceded task keeps
# its resources, so the worker does not start another stage (a reconstruct's grid, another map's fold) beside
# the fold it holds: a worker's memory is one stage's plus the chunk calls in flight, not two stages' at once.
# Its thread still runs chunk calls of any stage, so the cores stay busy while a fold waits.
STAGE_SLOT = "zipon-stage"

# dask priority of the calls of a running stage (ordered_tasks): above every stage task (run_many gives those
# their stage's level, 0..len(stages)), so a worker finishes the stages already started before it starts another:
# the folds in memory stay few, and a started stage's outputs come as early as they can
CALL_PRIORITY = 1000


_CONSUMING: "threading.Semaphore | None" = None
_CONSUMING_INIT = threading.Lock()


def _consuming_slots() -> "threading.Semaphore":
    """The semaphore of this worker process bounding the :func:`ordered_tasks` callers that consume results at a
    time: one per worker thread."""
    global _CONSUMING
    with _CONSUMING_INIT:
        if _CONSUMING is None:
            from distributed import get_worker

            _CONSUMING = threading.Semaphore(get_worker().state.nthreads)
    return _CONSUMING


@contextmanager
def _consuming_turn(usage: dict[str, float] | None):
    """Hold one of this worker process's :func:`_consuming_slots`; the wait for it goes to ``usage['waited_seconds']``
    (a stage's manifest records it: the time the stage stood in line, not working)."""
    slots, t0 = _consuming_slots(), time.perf_counter()
    with slots:
        if usage is not None:
            usage["waited_seconds"] = usage.get("waited_seconds", 0.0) + time.perf_counter() - t0
        yield


def _worker_client():
    """``distributed.worker_client()`` when this code runs in a dask.distributed worker, else None."""
    import sys

    if "distributed" not in sys.modules:  # never imported: certainly not a worker
        return None
    from distributed import get_worker, worker_client

    try:
        get_worker()
    except ValueError:
        return None
    return worker_client()


def _ordered_call(fn: Callable[[Any], Any], threads: int, item: Any) -> tuple[Any, int, float, float]:
    """``(fn(item), pid, CPU seconds of this process during the call, its peak RSS in MiB)``."""
    limit_native_threads(threads)
    cpu0 = time.process_time()
    result = fn(item)
    release_free_memory()
    return result, os.getpid(), time.process_time() - cpu0, peak_rss_mb()


def _stderr_console():
    from rich.console import Console

    return Console(stderr=True)


@dataclass
class Outcome:
    """What happened to one (scene, stage)."""

    scene: str
    stage: str
    status: str  # "ran", "skipped", "failed", "blocked"
    reason: str = ""
    seconds: float = 0.0
    summary: dict = field(default_factory=dict)
    error: str = ""


def run_stage(ws: Workspace, params: Params, stages: dict[str, StageSpec], scene: str, stage: str, **kw) -> Outcome:
    """:func:`_run_stage` holding the (scene, stage) lock (:mod:`pipeline.engine.locks`; fails fast with
    :class:`~pipeline.errors.LockedError`), after finishing or undoing a publication a killed run
    left and sweeping its temporary folders (:mod:`pipeline.engine.publication`).

    On an object-store data root (``ws.remote``, :mod:`pipeline.engine.fsroot`) this runs in the local cache, holding the
    object store's lock of (scene, stage), between a pull of the stage and its inputs and their publication."""
    if ws.remote is not None:
        from pipeline.engine.fsroot import remote_stage

        ups = upstream_stages(stages, params, scene, stage)
        with remote_stage(ws, scene, stage, {s: stages[s].outputs for s in (stage, *ups)}, ups) as publish_remote:
            outcome = run_stage(replace(ws, remote=None), params, stages, scene, stage, **kw)
            if outcome.status == "ran":
                publish_remote()
            return outcome
    outputs = [ws.artifact(name, scene) for name in stages[stage].outputs]
    with output_lock(ws.lock(scene, stage), f"scene {scene} stage {stage}"):
        recover(ws.journal(scene, stage), outputs, ws.manifest(scene, stage))
        sweep_tmp(ws.tmp_dir(scene), label=stage)
        check_inputs_unchanged(ws, scene, stage, upstream_stages(stages, params, scene, stage))
        return _run_stage(ws, params, stages, scene, stage, **kw)


def _run_stage(
    ws: Workspace,
    params: Params,
    stages: dict[str, StageSpec],
    scene: str,
    stage: str,
    *,
    force: bool = False,
    show_progress: bool = True,
    upstream: list[Outcome] | None = None,
) -> Outcome:
    """Run one stage of one scene if it is stale (or ``force``); publish its outputs and manifest as one set."""
    spec = stages[stage]
    blocked = [o for o in (upstream or []) if o.status in ("failed", "blocked")]
    if blocked:
        return Outcome(scene, stage, "blocked", reason=f"upstream {blocked[0].stage} {blocked[0].status}")
    in_digests = input_digests(ws, params, stages, spec, scene)
    reason = "forced" if force else staleness(ws, params, stages, spec, scene, in_digests)
    if not reason:
        return Outcome(scene, stage, "skipped", reason="up to date")
    t0, cpu0, counters0 = time.perf_counter(), time.process_time(), process_counters()
    started = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    tmp = new_tmp_dir(ws.tmp_dir(scene), stage)
    try:
        inputs = {}
        for name in spec.inputs:
            if name == SOURCE:  # one input per raw log: source, source_2, ...
                inputs.update({source_key(i): p for i, p in enumerate(source_paths(ws, params, scene))})
            else:
                inputs[name] = ws.artifact(name, scene)
        outputs = {name: tmp / ws.artifact(name, scene).name for name in spec.outputs}
        config, projection = spec.build_config(params, scene)
        ctx = StageContext(scene, stage, config, params.run, ws, inputs, outputs, digest_value(projection),
                           show_progress)
        summary = spec.load()(ctx) or {}
        records = {}
        for name, path in outputs.items():
            if not path.exists():
                raise StageError(f"stage {stage} (scene {scene}) did not write its output {name!r}")
            known = ctx.known_digests[name].known() if name in ctx.known_digests else None
            records[name] = OutputRecord(path=ws.relative(ws.artifact(name, scene)), digest=content_digest(path, known))
        seconds = time.perf_counter() - t0
        man = Manifest(
            stage=stage, scene=scene, code_version=__version__, code_digest=stage_code_digest(spec),
            code_files=codedeps.file_digests(spec.module),
            params=projection, params_digest=ctx.params_digest, inputs=in_digests, outputs=records,
            summary=summary, layout=dict(ARTIFACTS),
            timing={"started": started, "seconds": round(seconds, 3),
                    "cpu_seconds": round(time.process_time() - cpu0 + ctx.elsewhere["cpu_seconds"], 3),
                    "peak_rss_mb": round(max(peak_rss_mb(), ctx.elsewhere["peak_rss_mb"]), 1),
                    "waited_seconds": round(ctx.elsewhere["waited_seconds"], 3),
                    "native_threads": native_threads(),
                    "counters": counters_since(counters0),
                    "host": socket.gethostname(), "pid": os.getpid(), "python": platform.python_version()},
        )
        check_inputs_unchanged(ws, scene, stage, upstream_stages(stages, params, scene, stage),
                               {("raw_log" if k == SOURCE else k): v for k, v in in_digests.items()})
        publish_outputs(ws.journal(scene, stage), {ws.artifact(n, scene): p for n, p in outputs.items()},
                        ws.manifest(scene, stage), man)
        return Outcome(scene, stage, "ran", reason=reason, seconds=seconds, summary=summary)
    finally:
        remove(tmp)


def _task(ws, params, stages, scene, stage, force, show_progress, threads, *upstream):
    """dask task wrapper: never raises, so one scene's failure does not cancel the others."""
    limit_native_threads(threads)
    try:
        return run_stage(ws, params, stages, scene, stage, force=force, show_progress=show_progress,
                         upstream=list(upstream))
    except ZiponError as err:
        return Outcome(scene, stage, "failed", error=str(err))
    except OSError as err:  # disk full, read-only, permissions: the path and what to do, no traceback
        # an error without a path came from writing the outputs, which go to the scene's .tmp folder first
        where = f"{ws.tmp_dir(scene)}/ (writing the outputs)"
        return Outcome(scene, stage, "failed", error=os_error_message(err, where))
    except Exception as err:  # noqa: BLE001 - a bug, not bad input: keep the traceback for the report
        return Outcome(scene, stage, "failed", error=f"{type(err).__name__}: {err}\n{traceback.format_exc()}")
    finally:
        release_free_memory()  # the next stage this worker runs starts from what is still in use


def stage_threads(params: Params, spec: StageSpec, scenes_in_run: int, scheduler: str) -> int:
    """Native threads for one task of ``spec``: ``run.threads_per_worker``, times the workers each scene of the run
    has to itself when the run has fewer scenes than workers and the stage ``spreads_threads`` (one scene's
    reconstruct on 2 workers uses both cores), capped at the machine's cores. Not under the ``threads`` scheduler,
    whose tasks share one process and so its thread settings."""
    threads = params.run.threads_per_worker
    if not spec.spreads_threads or scheduler == "threads" or scenes_in_run <= 0:
        return threads
    share = max(1, params.run.workers // scenes_in_run)
    return max(threads, min(threads * share, os.cpu_count() or 1))


def run_many(
    ws: Workspace,
    params: Params,
    stages: dict[str, StageSpec],
    pairs: list[tuple[str, str]],
    *,
    force: bool = False,
    scheduler: str | None = None,
    show_progress: bool = True,
) -> list[Outcome]:
    """Run (scene, stage) pairs; independent scenes in parallel with dask (``params.run.scheduler``)."""
    import dask

    scheduler = scheduler or params.run.scheduler
    levels = stage_levels(stages)
    scenes_in_run = len({scene for scene, _ in pairs})
    # our own local cluster gives each worker one stage slot (see STAGE_SLOT); a cluster someone else started
    # offers no such resource, so there the stage tasks ask for none
    slot = {"resources": {STAGE_SLOT: 1}} if scheduler == "processes" else {}
    tasks: dict[tuple[str, str], Any] = {}
    for scene, stage in pairs:
        ups = [tasks[(scene, u)] for u in upstream_stages(stages, params, scene, stage) if (scene, u) in tasks]
        # priority and resources are read by dask.distributed only (stage_levels and STAGE_SLOT say why)
        with dask.annotate(priority=levels[stage], **slot):
            tasks[(scene, stage)] = dask.delayed(_task, pure=False)(
                ws, params, stages, scene, stage, force, show_progress,
                stage_threads(params, stages[stage], scenes_in_run, scheduler), *ups,
                dask_key_name=f"{stage}-{scene}",
            )
    if not tasks:
        return []
    values = list(tasks.values())
    if scheduler == "sync":
        results = dask.compute(*values, scheduler="sync")
    elif scheduler == "threads":
        results = dask.compute(*values, scheduler=scheduler, num_workers=params.run.workers)
    else:
        import logging

        from distributed import Client, LocalCluster

        # 'processes': a local dask.distributed cluster of single-threaded worker processes (not dask's
        # multiprocessing scheduler), so a stage can spread its own tasks over every worker (ordered_tasks)
        cluster = None
        if scheduler == "processes":
            # no queuing on the scheduler: a stage task waiting for its worker's STAGE_SLOT counts as that worker's
            # work, so queuing would hold back the chunk calls the seceded stage is waiting for (a deadlock)
            with dask.config.set({"distributed.scheduler.worker-saturation": "inf"}):
                cluster = LocalCluster(n_workers=params.run.workers, threads_per_worker=1, processes=True,
                                       memory_limit=0, dashboard_address=":0", silence_logs=logging.ERROR,
                                       resources={**params.run.encoder_resources, STAGE_SLOT: 1})
        try:
            with Client(cluster or scheduler) as client:
                results = dask.compute(*values, scheduler=client)
        finally:
            if cluster is not None:
                cluster.close()
    return list(results)
