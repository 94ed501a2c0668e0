"""Evaluator throughput: episodes per second per method, retrieve_map latency, and the paper-sized run.

    .venv/bin/python benchmarks/bench_eval.py                       # builds one simulated scene in a temp dir
    .venv/bin/python benchmarks/bench_eval.py --params PATH [--scene S]   # an existing workspace

Prints one JSON object per line (the built scene's maps come from the simulated perception models,
``encoders.simulated: perception``, and the CoW / ORION agents detect with the simulated detector):

- ``perception``: which perception model built each map and what detection runs on;
- ``retrieve_map``: ms per query (first call per text, i.e. MapQuery + candidates; and cached);
- ``episodes``: per method, episodes/s over one scene x 7 feedback settings x 5 seeds (one process),
  against the reference of the same episodes with a FRESH scene context per episode (no shared
  caches of FMM fields, viewpoints, ego views);
- ``paper_run``: the measured time of the 4 methods on one scene, scaled to 10 scenes x 12 goals x
  7 settings x 4 methods x 5 seeds on 2 worker processes (scenes are independent), with the
  goal of <= 600 s.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import emit

from orion_eval.agents import build_agent
from orion_eval.artifacts import Artifacts
from orion_eval.episode import run_episode
from orion_eval.run import scene_tasks
from orion_eval.scene import SceneContext
from orion_eval.user import FEEDBACK_SETTINGS
from pipeline.config import load_params
from pipeline.paths import Workspace

BUILD = """\
scenes:
  bench: {source: simulate}
simulate: {frames: 240, width: 320, height: 240}
encoders: {simulated: perception}
"""


def build(root: Path) -> Workspace:
    from pipeline.runner import plan, run_many
    from stages import STAGES

    (root / "params.yaml").write_text(BUILD)
    ws = Workspace.resolve(root / "params.yaml", data_dir=root / "data", manifests_dir=root / "manifests")
    params = load_params(ws.params_path)
    out = run_many(ws, params, STAGES, plan(STAGES, params, ["bench"]), show_progress=False)
    bad = [o for o in out if o.status not in ("ran", "skipped")]
    if bad:
        raise SystemExit(f"building the bench scene failed: {bad[0].stage}: {bad[0].error[:500]}")
    return ws


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--params", default=None)
    ap.add_argument("--scene", default=None)
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    tmp = None
    if args.params:
        ws = Workspace.resolve(args.params)
    else:
        tmp = tempfile.TemporaryDirectory()
        t = time.perf_counter()
        ws = build(Path(tmp.name))
        emit(**{"bench": "eval", "figure": "build_scene_s", "value": round(time.perf_counter() - t, 1)})
    params = load_params(ws.params_path)
    scene = args.scene or next(iter(params.scenes))
    arts = Artifacts(ws, params, scene)
    ctx = SceneContext(arts)
    from orion_eval.run import _detection_kind, _encoder_names

    encoders = _encoder_names(ws, params, scene)
    emit(**{"bench": "eval", "figure": "perception", "maps": {k: v["kind"] for k, v in encoders.items()},
            "detection": _detection_kind(params, encoders)})

    # retrieve_map: the first query of a text (MapQuery + candidates) and a repeated one
    names = [g.name for g in arts.goals.goals]
    pose = arts.routes.episodes[0].start
    from orion_eval.episode import EpisodeRun, Task
    from orion_eval.user import SimulatedUser

    g0 = arts.goals.goals[0]
    run = EpisodeRun(ctx, Task(scene, "vlmap", "yesno", 0, g0.id, "x", pose, 1.0),
                     SimulatedUser(ctx, g0, "yesno", np.random.default_rng(0)), 10, 5)
    arts.map_query("vlmap")  # load features and background scores once (not per query)
    first, again = [], []
    for n in names:
        t = time.perf_counter()
        run.modules.retrieve_map(n, "vlmap")
        first.append(time.perf_counter() - t)
        t = time.perf_counter()
        run.modules.retrieve_map(n, "vlmap")
        again.append(time.perf_counter() - t)
    emit(**{"bench": "eval", "figure": "retrieve_map_ms", "first_median": round(1e3 * float(np.median(first)), 2),
            "first_max": round(1e3 * float(np.max(first)), 2),
            "cached_median": round(1e3 * float(np.median(again)), 3), "queries": len(names),
            "goal_ms": 20})

    # episodes per method over every feedback setting and seed, one process
    seeds = list(range(args.seeds))
    goal_index = {g.id: i for i, g in enumerate(arts.goals.goals)}
    per_method = {}
    for method in ("human", "cow", "vlmap", "cf", "orion"):
        agent = build_agent(method, params)
        tasks = scene_tasks(arts, [method], list(FEEDBACK_SETTINGS), seeds)
        t = time.perf_counter()
        for task, goal in tasks:
            rng = np.random.default_rng([task.seed, goal_index[goal.id], FEEDBACK_SETTINGS.index(task.feedback)])
            run_episode(ctx, task, agent, goal, rng=rng)
        dt = time.perf_counter() - t
        # reference: the first 14 of the same episodes, each with a fresh scene context (no shared caches)
        ref = tasks[:14]
        t = time.perf_counter()
        for task, goal in ref:
            rng = np.random.default_rng([task.seed, goal_index[goal.id], FEEDBACK_SETTINGS.index(task.feedback)])
            run_episode(SceneContext(Artifacts(ws, params, scene, check=False)), task, agent, goal, rng=rng)
        dt_ref = time.perf_counter() - t
        per_method[method] = (len(tasks), dt)
        emit(**{"bench": "eval", "figure": "episodes_per_s", "method": method, "episodes": len(tasks),
                "seconds": round(dt, 2), "episodes_per_s": round(len(tasks) / dt, 2),
                "reference_fresh_context_episodes_per_s": round(len(ref) / dt_ref, 2)})

    # paper-sized run: 10 scenes x ~12 goals x 7 settings x 4 methods x 5 seeds on 2 processes
    four = ("cow", "vlmap", "cf", "orion")
    n_goals = len({g for g in (e.goal_id for e in arts.routes.episodes)})
    scene_s = sum(per_method[m][1] for m in four) * (12 / max(1, n_goals)) * (5 / len(seeds))
    total = 10 * scene_s / 2
    emit(**{"bench": "eval", "figure": "paper_run_estimate_s", "episodes": 10 * 12 * 7 * 4 * 5,
            "per_scene_s_one_core": round(scene_s, 1), "two_cores_s": round(total, 1), "goal_s": 600,
            "scene_goals_measured": n_goals, "note": "scaled from one measured scene; scenes run in "
            "parallel processes (eval.workers=2)"})
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
