"""The paper-sized evaluation, timed: 10 scenes, >= 117 goals, 7 feedback settings, 4 methods + the human
upper bound, 5 seeds, on ``eval.workers`` processes (goal: <= 600 s on 2 cores).

    .venv/bin/python benchmarks/bench_eval.py --workspace /tmp/bench_eval     # builds the scenes once, then evaluates
    .venv/bin/python benchmarks/bench_eval.py --workspace DIR --scenes 2 --seeds 1   # a smaller run
    .venv/bin/python benchmarks/bench_eval.py --params PATH                   # an existing workspace, its scenes

Building the scenes' artifacts is the batch pipeline's job and is NOT timed: with ``--workspace`` the
scenes ``bench_00``... (fresh procedural apartments, not the demo's) are written to ``DIR/params.yaml``
and built with ``zipon run``'s runner (``run.scheduler: processes``); a second call reuses them, stale ones
too unless ``--rebuild`` (the timing does not depend on them; the ``build`` line names every stale stage).
Their maps come from the simulated perception models (``encoders.simulated: perception``), and the CoW / ORION
agents detect with the simulated detector. The timed part is :func:`orion_eval.run.evaluate`
(results.json and the HTML report included) into ``DIR/eval``.

Prints one JSON object per line:

- ``build``: the scenes, how many stages ran or were reused (with every stale stage reused as it is, and why it
  is stale), and the (untimed) build seconds;
- ``perception``: which perception model built each map and what detection runs on;
- ``paper_run``: episodes, goals, the evaluation's wall seconds, episodes/s, workers and the 600 s goal; the
  CPU seconds of the evaluation's processes and the wall time they make on ``--workers`` idle cores (the
  machine may be shared: the wall time then says more about the other jobs than about the evaluator);
- ``table``: SR / SPL / SIT per method and feedback setting (percent, mean over seeds) and the cell's N;
- ``shape``: the qualitative checks (no-interaction SR below every feedback setting, VLMap and
  CF apart, CoW lowest, Wilcoxon p of ORION against each baseline per setting).
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

from _common import emit

from orion_eval.agents import AGENTS
from orion_eval.run import evaluate
from stages import STAGES
from orion_eval.user import FEEDBACK_SETTINGS
from pipeline.paramsfile import load_params
from pipeline.paths import Workspace

METHODS = list(AGENTS)  # every registered agent, in the paper's table order


def build_params(n_scenes: int, frames: int, prefix: str = "bench", seed: int = 0, rooms: int | None = None) -> str:
    """The bench workspace's params.yaml: ``n_scenes`` simulated apartments ``<prefix>_00``..., lean frames
    (320x240); ``seed`` is ``simulate.seed`` (each scene's seed derives from it and the scene's name); ``rooms``:
    every apartment has that many rooms (None: the simulator's default range)."""
    scenes = "".join(f"  {prefix}_{i:02d}: {{source: simulate}}\n" for i in range(n_scenes))
    size = "" if rooms is None else f", rooms_min: {rooms}, rooms_max: {rooms}"
    return (f"scenes:\n{scenes}"
            "run: {scheduler: processes, workers: 2}\n"
            f"simulate: {{frames: {frames}, width: 320, height: 240, seed: {seed}{size}}}\n"
            "encoders: {simulated: perception}\n"
            "eval: {workers: 2}\n")


def build(root: Path, n_scenes: int, frames: int, rebuild: bool = False, stages: list[str] | None = None,
          *, prefix: str = "bench", seed: int = 0, bench: str = "eval", rooms: int | None = None,
          reuse_stale: bool = False) -> Workspace:
    """Write (or keep) ``root/params.yaml`` and bring its scenes up to date: the pipeline reruns what is stale (a
    code, params or input change, :func:`pipeline.engine.stagegraph.staleness`) and reuses the rest, so a second call
    with nothing changed runs nothing. ``stages`` reruns only those stages (forced, e.g. goals and routes after
    their format changed). ``reuse_stale`` (and not ``rebuild``) keeps stale artifacts as they are, for a speed
    measurement that does not depend on them (rebuilding ten scenes after a map change takes long); the ``build``
    line then names every stale stage and why, so no figure is read off artifacts that silently lag the code."""
    from pipeline.engine.stagegraph import plan, stale_stages
    from pipeline.engine.runner import run_many

    root.mkdir(parents=True, exist_ok=True)
    text = build_params(n_scenes, frames, prefix, seed, rooms)
    path = root / "params.yaml"
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    ws = Workspace.resolve(path, data_dir=root / "data", manifests_dir=root / "manifests")
    params = load_params(ws.params_path)
    pairs = plan(STAGES, params, list(params.scenes), stages or None)
    if not stages:
        stale = stale_stages(ws, params, STAGES, pairs)
        if not stale or (reuse_stale and not rebuild):
            emit(bench=bench, figure="build", scenes=list(params.scenes), reused="all artifacts", stale=stale,
                 seconds_untimed=0.0)
            return ws
    t = time.perf_counter()
    out = run_many(ws, params, STAGES, pairs, force=bool(stages), show_progress=False)
    bad = [o for o in out if o.status not in ("ran", "skipped")]
    if bad:
        raise SystemExit(f"building {bad[0].scene} failed: {bad[0].stage}: {(bad[0].error or '')[:500]}")
    emit(bench=bench, figure="build", scenes=list(params.scenes), ran=sum(o.status == "ran" for o in out),
         reused=sum(o.status == "skipped" for o in out), seconds_untimed=round(time.perf_counter() - t, 1))
    return ws


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and its waited-for children (the evaluation's workers)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def shape(results: dict, feedback: list[str]) -> dict:
    """The expected qualitative outcome (the paper's), read off the results (True/False per check, with the figures)."""
    sr = {m: {f: results["overall"].get(m, {}).get(f, {}).get("SR") for f in feedback} for m in METHODS}
    with_fb = [f for f in feedback if f != "none"]
    out = {}
    if "none" in feedback:
        out["none_below_every_feedback"] = {m: all(sr[m][f] > sr[m]["none"] for f in with_fb)
                                            for m in METHODS if not AGENTS[m].upper_bound and sr[m]["none"] is not None}
    out["vlmap_cf_differ"] = sum(sr["vlmap"][f] != sr["cf"][f] for f in feedback)
    out["cow_lowest"] = {f: sr["cow"][f] <= min(sr[m][f] for m in ("vlmap", "cf", "orion")) for f in feedback}
    tests = {}
    for metric, rows in results.get("wilcoxon_by_feedback", {}).items():
        if metric != "SR":
            continue
        for r in rows:
            if "orion" in (r["a"], r["b"]):
                other = r["b"] if r["a"] == "orion" else r["a"]
                tests.setdefault(r["feedback"], {})[other] = r["p"]
    out["orion_vs_baselines_p"] = tests
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workspace", type=Path, default=Path("/tmp/bench_eval"),
                    help="folder for the bench scenes (built once, reused)")
    ap.add_argument("--params", default=None, help="evaluate an existing workspace instead (its scenes)")
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--frames", type=int, default=240, help="simulate.frames of the bench scenes")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--workers", type=int, default=2, help="eval.workers (processes)")
    ap.add_argument("--out", type=Path, default=None, help="evaluation output (default WORKSPACE/eval)")
    ap.add_argument("--rebuild", action="store_true",
                    help="rerun the bench scenes' stale stages (by default the timing reuses them as they are; the "
                         "build line names them)")
    ap.add_argument("--stages", nargs="*", default=None, help="rerun only these stages of the bench scenes (forced)")
    args = ap.parse_args()
    if args.params:
        ws = Workspace.resolve(args.params)
    else:
        ws = build(args.workspace, args.scenes, args.frames, args.rebuild, args.stages, reuse_stale=True)
    params = load_params(ws.params_path)
    params = params.model_copy(update={"eval": params.eval.model_copy(update={"workers": args.workers})})
    out = args.out or ws.params_path.parent / "eval"
    feedback = list(FEEDBACK_SETTINGS)
    load0 = os.getloadavg()[0]
    cpu0 = _cpu_seconds()
    t = time.perf_counter()
    res = evaluate(ws, params, STAGES, out, scenes=list(params.scenes), methods=METHODS, feedback=feedback,
                   seeds=list(range(args.seeds)), progress=False)
    seconds = time.perf_counter() - t
    cpu = _cpu_seconds() - cpu0
    run = res["run"]
    goals = len({(e["scene"], e["goal"]) for e in res["episodes"]})
    emit(bench="eval", figure="perception", maps=sorted({v["kind"] for enc in run["encoders"].values()
                                                         for v in enc.values()}),
         detection=sorted(set(run["detection"].values())))
    emit(bench="eval", figure="paper_run", scenes=len(run["scenes"]), goals=goals, feedback=len(feedback),
         methods=METHODS, seeds=args.seeds, episodes=run["episodes"], workers=args.workers,
         eval_seconds=run["seconds"], seconds_with_report=round(seconds, 1),
         episodes_per_s=run["episodes_per_s"], goal_s=600, out=str(out),
         # the machine may be shared: CPU seconds of this process and its (reaped) workers, and what they make
         # on the requested cores alone when the scenes balance over the workers
         cpu_seconds=round(cpu, 1), cpu_seconds_per_episode=round(cpu / max(run["episodes"], 1), 4),
         two_core_estimate_s=round(cpu / args.workers, 1), load_avg_1m_at_start=round(load0, 2))
    emit(bench="eval", figure="table", metrics=["SR", "SPL", "SIT", "N"],
         rows={m: {f: [c.get("SR"), c.get("SPL"), c.get("SIT"), c.get("episodes")]
                   for f, c in res["overall"].get(m, {}).items()} for m in METHODS})
    emit(bench="eval", figure="shape", **shape(res, feedback))


if __name__ == "__main__":
    main()
