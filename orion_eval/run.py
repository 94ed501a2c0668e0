"""``zipon eval``: every (scene, method, feedback setting, seed, goal) episode, metrics, and the report.

The unit of work is one scene (:func:`evaluate_scene`, a pure function of the artifacts and params
returning its episode results); scenes are mapped over ``eval.workers`` processes with dask, the
serial path calling the same function. Within a scene, each (seed, setting, method) run visits the
scene's goals in the fixed goals.zarr order, and an agent with ``persistent_memory`` (ORION) carries
its memory from one goal to the next, as in the paper (corrective feedback helps only when a wrong
object found for one goal is the right object of a later goal); the other methods have no memory.
Per goal and seed the episode is ``routes.for_goal(goal)[seed % n]`` with its start heading turned
by 90 deg per pass over the goal's episodes (:func:`orion_eval.episode.start_pose`; in a building the goal's
episodes alternate between its floor and other floors, every second goal starting with the other floors:
:func:`goal_episodes`); the user's
draws are seeded by ``(seed, goal index)``, the same in every feedback setting (paired settings: a (seed, goal)
is asked the same at the same place whatever the setting, so settings differ only in what is said). Results
are identical for identical inputs.
"""

from __future__ import annotations

import gzip
import json
import math
import sys
import time
from pathlib import Path
from typing import Mapping

import numpy as np

from orion_eval.agents import AgentResources, build_agent
from orion_eval.episode import Task, run_episode, start_pose
from orion_eval.scene import SceneContext
from orion_eval.user import FEEDBACK_SETTINGS, HUMAN_FEEDBACK
from pipeline.config import Params
from pipeline.errors import ConfigError
from pipeline.paths import Workspace
from pipeline.scene import Scene
from pipeline.store import write_text_atomic


def scene_tasks(scene: Scene, methods, feedback, seeds) -> list[tuple[Task, object]]:
    """(task, goal view) pairs of one scene in a fixed order (seed, setting, method, goal): the goals of one
    (seed, setting, method) run are consecutive, in goals.zarr order (the order memory is carried in)."""
    out = []
    routes, goals = scene.routes, scene.goals
    for seed in seeds:
        for fb in feedback:
            for method in methods:
                for k, goal in enumerate(goals.goals):
                    eps = goal_episodes(routes, goal, k)
                    if not eps:
                        continue  # unreachable goal: reported by the routes stage, not an episode
                    e = eps[seed % len(eps)]
                    p0 = start_pose(e.start, seed, len(eps))
                    out.append((Task(scene.name, method, fb, int(seed), goal.id, e.id, p0, float(e.geodesic_m),
                                     int(e.start_floor)), goal))
    return out


def goal_episodes(routes, goal, index: int = 0) -> list:
    """A goal's episodes in the order seeds take them (``seed % n``): routes.zarr's order; in a building, taken in
    turn from the goal's floor and from other floors, the goal's floor first for even goal ``index`` (goals.zarr
    order) and the other floors first for odd ones, so that one seed already runs cross-floor episodes (of every
    second goal) and two seeds run both kinds of every goal that has them."""
    eps = routes.for_goal(goal.id)
    same = [e for e in eps if e.start_floor == goal.floor]
    cross = [e for e in eps if e.start_floor != goal.floor]
    if not cross:
        return eps
    first, then = (same, cross) if index % 2 == 0 else (cross, same)
    n = max(len(same), len(cross))
    return [e for i in range(n) for e in (first[i:i + 1] + then[i:i + 1])]


def evaluate_scene(ws: Workspace, params: Params, stages: Mapping, scene: str, methods, feedback, seeds,
                   log_dir: Path | None = None, threads: int = 1, agent_classes: dict | None = None) -> list[dict]:
    """All episodes of one scene (the unit of work); writes ``log_dir/<scene>.episodes.jsonl.gz`` when given.
    ``stages``: the stage registry (``stages.STAGES``: which stage produces which artifact).
    ``agent_classes`` maps method names to user :class:`~orion_eval.agents.Agent` subclasses (beside the registry)."""
    from pipeline.engine.process import limit_native_threads

    limit_native_threads(threads)
    ctx = SceneContext(Scene(ws, params, scene, stages, check=True))
    lp = params.eval.llm
    client = llm_user = None
    if lp.base_url:
        from orion_eval.llm import ChatClient, LLMUser

        client = ChatClient.from_params(lp)
        if lp.roles in ("user", "both"):
            llm_user = lambda goal: LLMUser(client, goal)  # noqa: E731
    resources = AgentResources(llm=client)
    agents = {m: build_agent(m, params, resources, agent_classes) for m in methods}
    goal_index = {g.id: i for i, g in enumerate(ctx.scene.goals.goals)}
    results = []
    memories: dict[tuple, object] = {}  # (method, setting, seed) -> the memory carried across the scene's goals
    for task, goal in scene_tasks(ctx.scene, methods, feedback, seeds):
        rng = np.random.default_rng([task.seed, goal_index[goal.id]])  # not the setting: paired settings
        memory = None
        if getattr(agents[task.method], "persistent_memory", False):
            from orion_eval.modules import new_memory

            key = (task.method, task.feedback, task.seed)
            if key not in memories:
                memories[key] = new_memory(ctx)
            memory = memories[key]
        t0 = time.perf_counter()
        res = run_episode(ctx, task, agents[task.method], goal, rng=rng, llm_user=llm_user, memory=memory)
        res["seconds"] = round(time.perf_counter() - t0, 5)
        results.append(res)
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        with gzip.open(log_dir / f"{scene}.episodes.jsonl.gz", "wt") as f:
            for r in results:
                f.write(json.dumps({k: v for k, v in r.items() if k != "seconds"}, sort_keys=True) + "\n")
    return results


def _resolve(params: Params, scenes, methods, feedback, seeds, agent_classes=None):
    ep = params.eval
    scenes = list(scenes or ep.scenes or params.scenes)
    unknown = [s for s in scenes if s not in params.scenes]
    if unknown:
        raise ConfigError(f"-s/--scene: unknown scene(s) {unknown}; params.yaml has {sorted(params.scenes)}")
    from orion_eval.agents import AGENTS, agent_class
    from pipeline import plugins

    # names are checked against their registries here (params spell none of them); None = every built-in one
    source = "--methods" if methods else "eval.methods"
    usable = [m for m, cls in AGENTS.items() if m in plugins.BUILT_IN_AGENTS and cls.missing(params) is None]
    methods = list(methods or ep.methods or [m for m in usable if AGENTS[m].by_default])
    classes = {**(agent_classes or {})}
    for m in methods:  # the caller's classes, then the registry: built in or an installed package's
        if m not in classes and (cls := agent_class(m)) is not None:
            classes[m] = cls
    bad = [m for m in methods if m not in classes]
    if bad:
        installed = [m for m in plugins.agent_names() if m not in plugins.BUILT_IN_AGENTS]
        raise ConfigError(f"{source}: unknown method(s) {bad}; choose from {usable}"
                          + (f" or the installed {installed}" if installed else ""))
    for m in methods:
        if (why := classes[m].missing(params)) is not None:
            raise ConfigError(f"{source}: method {m!r} cannot run: {why}")
    source = "--feedback" if feedback else "eval.feedback"
    feedback = list(feedback or ep.feedback or FEEDBACK_SETTINGS)
    bad = [f for f in feedback if f not in (*FEEDBACK_SETTINGS, HUMAN_FEEDBACK)]
    if bad:
        raise ConfigError(f"{source}: unknown setting(s) {bad}; choose from {[*FEEDBACK_SETTINGS, HUMAN_FEEDBACK]}")
    seeds = [int(s) for s in (seeds if seeds is not None else ep.seeds)]
    return scenes, methods, feedback, seeds


def evaluate(ws: Workspace, params: Params, stages: Mapping, out_dir: Path, scenes=None, methods=None, feedback=None,
             seeds=None, *, progress: bool = True, report: bool = True, agent_classes: dict | None = None,
             strict: bool = False) -> dict:
    """Evaluate, write ``out_dir/results.json`` (+ episode logs, + the HTML report) and return the results: the
    evaluator behind :func:`zipon.run_eval`, the one entry the CLI, the demo and the API call.

    ``strict``: a stored human-answered episode of a goal no longer in the goals store is an error (by default it is
    left out with a warning naming it).

    ``stages``: the stage registry (``stages.STAGES``), which says which stage produces which artifact.

    ``agent_classes`` {name: Agent subclass} adds user agents to the registry's for this run (``methods``
    names them); they must be importable by name when ``eval.workers`` > 1 (worker processes).
    """
    from orion_eval.metrics import summarize

    out_dir = Path(out_dir)
    scenes, methods, feedback, seeds = _resolve(params, scenes, methods, feedback, seeds, agent_classes)
    goal_ids = {}
    for s in scenes:  # fail early, before any worker starts, on missing or mismatched artifacts
        goal_ids[s] = {g.id for g in Scene(ws, params, s, stages, check=True).goals.goals}
    artifacts, stale = provenance(ws, params, stages, scenes)
    if stale:
        lines = "".join(f"\n  {k}: {why}" for k, why in stale.items())
        print(f"eval: evaluating these stages' artifacts as built, although they lag their code, params or inputs "
              f"(results.json run.stale; rerun them: zipon run):{lines}", file=sys.stderr, flush=True)
    if params.eval.llm.base_url:
        from orion_eval.llm import check_llm_params

        check_llm_params(params.eval.llm)
    human = human_episodes(ws, scenes, methods, goal_ids, strict=strict) if HUMAN_FEEDBACK in feedback else []
    simulated = [f for f in feedback if f != HUMAN_FEEDBACK]
    t0 = time.perf_counter()
    log_dir = out_dir / "episodes"
    workers = min(params.eval.workers, len(scenes))
    if workers > 1:
        per_scene = map_processes(evaluate_scene, [(ws, params, stages, s, methods, simulated, seeds, log_dir)
                                                   for s in scenes], workers, agent_classes=agent_classes)
    else:
        per_scene = []
        for s in scenes:
            if progress:
                from rich.console import Console

                Console(stderr=True).print(f"[dim]eval:[/dim] scene {s}")
            per_scene.append(evaluate_scene(ws, params, stages, s, methods, simulated, seeds, log_dir,
                                            agent_classes=agent_classes))
    episodes = [r for rs in per_scene for r in rs] + human
    seconds = time.perf_counter() - t0
    results = summarize(episodes, methods=methods, feedback=feedback, seeds=seeds, scenes=scenes,
                        max_turns=params.eval.max_talk_turns)
    results["run"] = {"scenes": scenes, "methods": methods, "feedback": feedback, "seeds": seeds,
                      "episodes": len(episodes), "seconds": round(seconds, 2),
                      "episodes_per_s": round(len(episodes) / seconds, 2) if seconds > 0 else None,
                      "success_rule": params.eval.success_rule, "max_talk_turns": params.eval.max_talk_turns,
                      "encoders": {s: _encoder_names(ws, params, s) for s in scenes},
                      "artifacts": artifacts, "stale": stale}
    results["run"]["detection"] = {s: _detection_kind(params, results["run"]["encoders"][s]) for s in scenes}
    out_dir.mkdir(parents=True, exist_ok=True)
    results = finite_json(results)  # NaN / inf (a statistic of too few episodes) are null: results.json is JSON
    write_text_atomic(out_dir / "results.json", json.dumps(results, indent=2, sort_keys=True, allow_nan=False) + "\n")
    if report:
        from orion_eval.report import write_report

        write_report(results, out_dir, ws=ws, params=params)
    return results


def finite_json(value):
    """``value`` with every NaN or infinite float replaced by None (JSON has neither; ``json.dumps`` would write
    ``NaN``, which no strict JSON reader accepts)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, np.floating):
        return finite_json(float(value))
    return value


def provenance(ws: Workspace, params: Params, stages: Mapping, scenes: list[str]) -> tuple[dict, dict]:
    """What an evaluation reads, for its results: each scene's artifacts as ``{artifact: digest}`` (the digests the
    publishing manifests record), and ``{"scene/stage": why}`` for each stage whose artifacts lag their code, params
    or upstream artifacts (:func:`pipeline.engine.stagegraph.staleness`, as ``zipon status`` says). Those are evaluated as
    built (a built version is a version), but the results say so. The stages that read a scene's raw data are
    left out of the staleness check: hashing a recording's every byte is ``zipon status``'s job, not each
    evaluation's."""
    from pipeline.engine.manifest import Manifest
    from pipeline.engine.stagegraph import SOURCE, plan, stale_stages

    pairs = plan(stages, params, scenes)
    artifacts: dict[str, dict[str, str]] = {}
    for scene, stage in pairs:
        man = Manifest.read(ws.manifest(scene, stage))
        if man is not None:
            artifacts.setdefault(scene, {}).update({name: out.digest for name, out in sorted(man.outputs.items())})
    return artifacts, stale_stages(ws, params, stages, [(sc, st) for sc, st in pairs if SOURCE not in stages[st].inputs])


def map_processes(fn, args: list[tuple], workers: int, **kwargs) -> list:
    """``[fn(*a, **kwargs) for a in args]`` over ``workers`` processes (dask's process scheduler), each task handed
    out alone as a process frees up: dask's default gives a process 6 tasks at once, which ran up to 6 scenes in one
    process while the others idled."""
    import dask

    tasks = [dask.delayed(fn, pure=False)(*a, **kwargs) for a in args]
    return list(dask.compute(*tasks, scheduler="processes", num_workers=workers, chunksize=1))


def human_episodes_path(ws: Workspace, scene: str) -> Path:
    """Where the episodes a person answered for ``scene`` are stored (one JSON record a line, appended)."""
    return Path(ws.data_dir) / "eval" / HUMAN_FEEDBACK / f"{scene}.episodes.jsonl"


def human_episodes(ws: Workspace, scenes: list[str], methods: list[str], goal_ids: dict[str, set[str]], *,
                   strict: bool = False) -> list[dict]:
    """The stored human-answered episodes of ``scenes`` played with ``methods``, each record validated
    (:mod:`orion_eval.records`); records of goals not in ``goal_ids[scene]`` are left out with a warning naming them
    (refused when ``strict``). A ConfigError when none are left (so ``-f human`` never reports an empty row)."""
    from orion_eval.records import read_human_episodes

    found = []
    for scene in scenes:
        path = human_episodes_path(ws, scene)
        if not path.is_file():
            continue
        read = read_human_episodes(path, scene, goal_ids[scene], methods, strict=strict)
        found += read.records
        if read.dropped:
            left = ", ".join(f"{g} ({n} episode{'s' * (n > 1)})" for g, n in sorted(read.dropped.items()))
            print(f"eval: {path}: left out the episodes of goals no longer in scene {scene}'s goals store: {left} "
                  f"(--strict refuses them)", file=sys.stderr, flush=True)
    if not found:
        raise ConfigError(f"--feedback {HUMAN_FEEDBACK}: no human-answered episodes of {methods} stored for "
                          f"{scenes} (play some in `zipon annotate`, tab Play; they are kept in "
                          f"{human_episodes_path(ws, scenes[0]).parent})")
    return found


#: what the CoW and ORION agents detect with when the maps come from simulated perception (orion_eval.detector)
DETECTOR_KIND = ("simulated detectors (orion_eval.detector), not trained models: ORION's open-vocabulary detector "
                 "(Grounding-DINO-like recall vs size / occlusion, CLIP-similar false positives) and CoW's CLIP "
                 "Grad-CAM saliency localiser (lower recall, 7x7-patch boxes, wider CLIP confusions)")


def _encoder_names(ws, params, scene) -> dict:
    from pipeline.maps.store import SemanticMap

    out = {}
    for which in ("vlmap", "cfmap"):
        p = ws.artifact(which, scene)
        if p.exists():
            e = SemanticMap(p).encoder
            out[which] = {"name": e.get("name"), "diagnostic": bool(e.get("diagnostic")),
                          "kind": e.get("kind") or f"{e.get('name')} (a real encoder, weights {e.get('weights_file')})"}
    return out


def _detection_kind(params, encoders: dict) -> str:
    """What detect_object runs on: the simulated detector with simulated perception, else the encoder's features."""
    detect = params.eval.detect_encoder or encoders.get("vlmap", {}).get("name")
    if str(detect).startswith("simulated_"):
        return DETECTOR_KIND
    return f"ego-view features of the {detect} encoder" + (" (ground truth: diagnostic)" if detect == "oracle" else "")
