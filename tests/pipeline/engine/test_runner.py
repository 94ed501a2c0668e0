import json
import os
import signal
import subprocess
import sys
import time

import pytest
import zarr

from pipeline.paramsfile import load_params
from pipeline.errors import ConfigError, ZiponError
from pipeline.engine.manifest import Manifest
from pipeline.engine.stagegraph import plan, staleness
from pipeline.engine.runner import run_many, run_stage
from pipeline.store import content_digest
from pipeline.engine.verify import verify_all
from tests.fixtures.toy_stages import TOY_STAGES


def run_all(ws, overrides=(), **kw):
    params = load_params(ws.params_path, overrides)
    return params, run_many(ws, params, TOY_STAGES, plan(TOY_STAGES, params, list(params.scenes)),
                            show_progress=False, **kw)


def test_runs_then_skips_and_reruns_only_what_changed(workspace):
    params, first = run_all(workspace, ["simulate.frames=8"])
    assert [(o.scene, o.stage, o.status) for o in first] == [
        ("s0", "simulate", "ran"), ("s0", "ingest", "ran"), ("s1", "simulate", "ran"), ("s1", "ingest", "ran")]
    _, second = run_all(workspace, ["simulate.frames=8"])
    assert {o.status for o in second} == {"skipped"}
    # ingest params only touch ingest; simulate params touch both (ingest sees a new input digest)
    _, third = run_all(workspace, ["simulate.frames=8", "ingest.block_frames=4"])
    assert [o.status for o in third] == ["skipped", "ran", "skipped", "ran"]
    _, fourth = run_all(workspace, ["simulate.frames=9", "ingest.block_frames=4"])
    assert [o.status for o in fourth] == ["ran", "ran", "ran", "ran"]
    assert fourth[0].reason == "params: simulate.frames 8 -> 9"
    assert fourth[1].reason == "input changed: source"


def test_manifest_records_lineage_and_is_deterministic(workspace, tmp_path):
    run_all(workspace, ["simulate.frames=8"])
    sim = Manifest.read(workspace.manifest("s0", "simulate"))
    ing = Manifest.read(workspace.manifest("s0", "ingest"))
    assert ing.inputs["source"] == sim.outputs["raw_log"].digest
    assert ing.outputs["frames"].path == "data/artifacts/s0/frames.zarr"
    assert ing.summary == {"rows": 8, "sum": int(ing.summary["sum"])}
    assert ing.params == {"ingest": ing.params["ingest"], "scenes.s0.format": "auto"}
    digest = ing.outputs["frames"].digest
    # a forced rerun and a run elsewhere give the same content digest
    run_all(workspace, ["simulate.frames=8"], force=True)
    assert Manifest.read(workspace.manifest("s0", "ingest")).outputs["frames"].digest == digest
    assert content_digest(workspace.artifact("frames", "s0")) == digest


def test_failure_keeps_previous_artifact_and_leaves_no_partial_store(workspace, monkeypatch):
    params, _ = run_all(workspace, ["simulate.frames=8"])
    before = content_digest(workspace.artifact("frames", "s0"))
    monkeypatch.setenv("TOY_FAIL", "1")
    _, outcomes = run_all(workspace, ["simulate.frames=8"], force=True)
    assert {o.status for o in outcomes if o.stage == "ingest"} == {"failed"}
    assert "toy failure mid-write" in outcomes[1].error
    assert content_digest(workspace.artifact("frames", "s0")) == before
    assert not any(workspace.tmp_dir("s0").iterdir())
    assert all(r.ok for r in verify_all(workspace, params, TOY_STAGES))


def test_killed_run_leaves_no_finished_looking_store(workspace, tmp_path):
    run_all(workspace, ["simulate.frames=8"], )
    frames = workspace.artifact("frames", "s0")
    before = content_digest(frames)
    pause = tmp_path / "paused"
    code = (
        "from pipeline.paramsfile import load_params; from pipeline.paths import Workspace;"
        "from pipeline.engine.runner import run_stage; from tests.fixtures.toy_stages import TOY_STAGES;"
        f"ws = Workspace.resolve({str(workspace.params_path)!r});"
        "p = load_params(ws.params_path, ['simulate.frames=8']);"
        "run_stage(ws, p, TOY_STAGES, 's0', 'ingest', force=True, show_progress=False)"
    )
    env = {**os.environ, "TOY_PAUSE_FILE": str(pause)}
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, cwd=str(__import__("tests").__path__[0] + "/.."))
    deadline = time.time() + 60
    while not pause.exists() and time.time() < deadline:
        time.sleep(0.1)
    assert pause.exists(), "the stage never reached its pause point"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert content_digest(frames) == before  # previous version intact
    leftovers = list(workspace.tmp_dir("s0").iterdir())
    assert leftovers and all(p.name.startswith("ingest@") for p in leftovers)  # only under .tmp/
    # the next run is not fooled (still up to date) and a forced run sweeps the dead run's leftovers
    params = load_params(workspace.params_path, ["simulate.frames=8"])
    assert staleness(workspace, params, TOY_STAGES, TOY_STAGES["ingest"], "s0") == ""
    assert run_stage(workspace, params, TOY_STAGES, "s0", "ingest", force=True, show_progress=False).status == "ran"
    assert not any(workspace.tmp_dir("s0").iterdir())


def test_verify_detects_tampering(workspace):
    params, _ = run_all(workspace, ["simulate.frames=8"])
    arr = zarr.open_array(str(workspace.artifact("frames", "s1") / "values"), mode="r+")
    arr[0, 0] = (int(arr[0, 0]) + 1) % 256
    rows = {(r.scene, r.stage): r for r in verify_all(workspace, params, TOY_STAGES)}
    assert rows[("s0", "ingest")].ok and not rows[("s1", "ingest")].ok
    assert "digest" in rows[("s1", "ingest")].problem


def test_staleness_reasons(workspace):
    params = load_params(workspace.params_path, ["simulate.frames=8"])
    spec = TOY_STAGES["ingest"]
    assert staleness(workspace, params, TOY_STAGES, spec, "s0") == "never run"
    run_all(workspace, ["simulate.frames=8"])
    assert staleness(workspace, params, TOY_STAGES, spec, "s0") == ""
    p2 = load_params(workspace.params_path, ["simulate.frames=8", "ingest.max_pose_gap_s=0.5"])
    assert staleness(workspace, p2, TOY_STAGES, spec, "s0") == "params: ingest.max_pose_gap_s 0.1 -> 0.5"
    # settings in no digest: scheduling, devices, queries
    p3 = load_params(workspace.params_path, ["simulate.frames=8", "run.workers=1", "run.device=cpu",
                                             "query.min_candidate_score=0.2"])
    assert staleness(workspace, p3, TOY_STAGES, spec, "s0") == ""
    journal = workspace.journal("s0", "ingest")
    journal.write_text("{}")
    assert staleness(workspace, params, TOY_STAGES, spec, "s0").startswith("publication interrupted")
    journal.unlink()
    import shutil

    shutil.rmtree(workspace.artifact("frames", "s0"))
    assert staleness(workspace, params, TOY_STAGES, spec, "s0") == "output frames missing"


def test_a_dask_scheduler_and_workers_started_as_on_a_cluster_run_the_scenes(workspace, tmp_path):
    """`dask scheduler` and `dask worker` processes (as a cluster or a SLURM job starts them, sharing the data
    root's filesystem) run the scenes; a serial rerun then finds everything up to date."""
    dask_cli = [sys.executable, "-m", "dask"]
    info = tmp_path / "scheduler.json"
    repo = str(__import__("tests").__path__[0] + "/..")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([repo, os.environ.get("PYTHONPATH", "")])}
    procs = [subprocess.Popen(dask_cli + ["scheduler", "--scheduler-file", str(info), "--port", "0",
                                         "--no-dashboard"], env=env, cwd=repo,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.time() + 60
        while not info.exists() and time.time() < deadline:
            time.sleep(0.2)
        assert info.exists(), "the dask scheduler did not start"
        procs.append(subprocess.Popen(dask_cli + ["worker", "--scheduler-file", str(info), "--nworkers", "2",
                                                  "--nthreads", "1", "--no-dashboard"], env=env, cwd=repo,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        address = json.loads(info.read_text())["address"]
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
            pids = set(client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids
        _, outcomes = run_all(workspace, ["simulate.frames=8"], scheduler=address)
        assert [o.status for o in outcomes] == ["ran"] * 4
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            proc.wait(timeout=30)
    _, serial = run_all(workspace, ["simulate.frames=8"])
    assert {o.status for o in serial} == {"skipped"}  # the cluster's results are the serial ones


def test_config_errors_name_the_key(workspace):
    with pytest.raises(ConfigError, match=r"ingest\.block_frames: Input should be greater than 0"):
        load_params(workspace.params_path, ["ingest.block_frames=0"])
    with pytest.raises(ConfigError, match=r"simulate\.framez: Extra inputs are not permitted"):
        load_params(workspace.params_path, ["simulate.framez=3"])
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        load_params(workspace.params_path, ["simulate.frames"])


def _square_and_worker(x):
    from distributed import get_worker

    if x == 99:
        raise ValueError("item 99 is bad")
    time.sleep(0.05)
    return x * x, get_worker().address


def _ordered_in_a_worker(items):
    from pipeline.engine.runner import ordered_tasks

    usage = {}
    return list(ordered_tasks(_square_and_worker, items, name="square", usage=usage)), usage


def test_ordered_tasks_run_on_every_worker_and_yield_in_item_order():
    from distributed import Client, LocalCluster

    from pipeline.engine.runner import ordered_tasks

    assert list(ordered_tasks(lambda x: x * x, range(5), name="square")) == [0, 1, 4, 9, 16]  # no cluster: here
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        out, usage = client.submit(_ordered_in_a_worker, list(range(12))).result()  # a stage task spreading its items
        assert [v for v, _ in out] == [x * x for x in range(12)]
        assert len({w for _, w in out}) == 2
        assert set(usage) == {"waited_seconds"}  # in-process workers: this process's CPU time counts every call
        assert usage["waited_seconds"] < 1.0  # no other stage held the worker's turn
        with pytest.raises(ValueError, match="item 99 is bad"):
            client.submit(_ordered_in_a_worker, [1, 99, 2]).result()


def _consume(items):
    """A stage task folding its items' results: (time of its first result, of its last, the results)."""
    from pipeline.engine.runner import ordered_tasks

    times, out, usage = [], [], {}
    for value in ordered_tasks(_square_and_worker, items, name="square", usage=usage):
        times.append(time.monotonic())
        out.append(value[0])
    return times[0], times[-1], out, usage["waited_seconds"]


def test_a_worker_folds_one_stage_at_a_time_while_the_others_wait():
    """Three stage tasks on a one-thread worker all start (each secedes at once), but only one at a time consumes
    results (its folds are the memory a map stage holds); every one finishes, none deadlocks."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        runs = client.gather([client.submit(_consume, list(range(k, k + 6)), pure=False) for k in (0, 10, 20)])
    assert [out for _, _, out, _ in runs] == [[x * x for x in range(k, k + 6)] for k in (0, 10, 20)]
    spans = sorted((first, last) for first, last, _, _ in runs)
    assert all(a_last < b_first for (_, a_last), (b_first, _) in zip(spans, spans[1:]))
    waits = [waited for *_, waited in runs]  # recorded for the manifest: the time a stage stood in line
    assert min(waits) >= 0 and max(waits) > 0.05  # the last in line waited for at least one 50 ms call


def _ordered_with_resources(items, resources):
    from pipeline.engine.runner import ordered_tasks

    return list(ordered_tasks(_square_and_worker, items, name="square", resources=resources))


def test_ordered_tasks_asking_for_a_resource_run_only_on_the_workers_that_offer_it():
    """A map stage's chunk tasks with run.encoder_resources {GPU: 1}: one CPU worker and one 'GPU' worker; every
    call lands on the GPU worker, the results come in order, and a resource nobody offers is an error."""
    from distributed import Client, Scheduler, SpecCluster, Worker

    spec = {"cpu": {"cls": Worker, "options": {"nthreads": 1}},
            "gpu": {"cls": Worker, "options": {"nthreads": 1, "resources": {"GPU": 1}}}}
    with SpecCluster(workers=spec, scheduler={"cls": Scheduler, "options": {"dashboard_address": ":0"}}) as cluster, \
            Client(cluster) as client:
        gpu = next(a for a, w in client.scheduler_info()["workers"].items() if w.get("resources"))
        out = client.submit(_ordered_with_resources, list(range(6)), {"GPU": 1}).result()
        assert [v for v, _ in out] == [x * x for x in range(6)]
        assert {w for _, w in out} == {gpu}
        with pytest.raises(ZiponError, match=r"run\.encoder_resources \{'TPU': 1\}: no dask worker offers them"):
            client.submit(_ordered_with_resources, [1, 2], {"TPU": 1}).result()


def test_a_stage_that_spreads_threads_takes_the_workers_idle_scenes_leave(workspace):
    from pipeline.engine.runner import stage_threads
    from stages import STAGES

    cores = os.cpu_count() or 1
    params = load_params(workspace.params_path, ["run.workers=2"])
    recon, vlmap = STAGES["reconstruct"], STAGES["vlmap"]
    assert stage_threads(params, recon, 1, "processes") == min(2, cores)
    assert stage_threads(params, recon, 2, "processes") == 1
    assert stage_threads(params, vlmap, 1, "processes") == 1  # maps spread their chunks over workers instead
    assert stage_threads(params, recon, 1, "threads") == 1  # one shared process: its settings are everyone's
    many = load_params(workspace.params_path, ["run.workers=64", "run.threads_per_worker=2"])
    assert stage_threads(many, recon, 1, "processes") == max(2, cores)  # never more than the machine's cores
