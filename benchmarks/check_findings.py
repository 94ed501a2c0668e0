"""Does the evaluator reproduce the ORION paper's findings about feedback? (A check, not a timed test.)

    .venv/bin/python benchmarks/check_findings.py --workspace /tmp/findings --scenes 3   # builds, then evaluates
    .venv/bin/python benchmarks/check_findings.py --workspace /tmp/findings --scenes 10 --seeds 5
    .venv/bin/python benchmarks/check_findings.py --workspace /tmp/findings --scenes 10 --ablations

The scenes ``findings_00``... are fresh procedural apartments that no test, demo or other benchmark uses
(their own names and ``simulate.seed`` 2027), built once with the batch pipeline (untimed; a second call reruns
only what a code, params or input change made stale, so no figure comes from goals or maps that lag the code;
``--reuse-stale`` keeps them as they are and the ``build`` line names each one), their maps from the simulated
perception models, the CoW and ORION detectors simulated (:mod:`orion_eval.detector`). They are sized like the
paper's HM3D scenes (``--rooms`` 10: about HM3D's 112.5 m2 of navigable floor a scene; the check prints each
scene's), and an episode ends as the paper's do, on success or after I_max questions (``--max-steps`` is only a
far bound against a runaway; the report counts the episodes it ended).
Every method runs the same controller with its own modules (:mod:`orion_eval.agents.controller`); nothing in it or
in the perception models is set from these results.

Prints the SR / SPL / SIT tables next to the paper's Table I (single feedback) and Table II (mixed), the
Spearman rank correlation and the mean absolute difference over the 28 method x setting cells, and the
paper's findings (1)-(6) as holds / does not hold with the figures. Every figure has a 95 % interval from a
bootstrap over goals (a goal's episodes, all seeds and settings, resampled together; ``--boot`` draws).

``--ablations`` also evaluates ORION's ablations in the mixed setting (ORION without its memory, exploration,
detector or map: the same controller with that module left out, :mod:`orion_eval.agents.orion`) and prints them
next to the paper's Table II (lower part), with the paper's reading of them as holds / does not hold: every module
removed costs SR, the map the most, the memory the least.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from _common import emit
from findings_drivers import driver_figures, paper_mix_weights, print_drivers, scene_statistics
from benchmarks.bench_eval import build, build_params
from pydantic import ValidationError
from scipy.stats import spearmanr

from orion_eval.records import EpisodeOutcome
from orion_eval.report import stale_text
from orion_eval.run import evaluate
from stages import STAGES
from orion_eval.user import FEEDBACK_SETTINGS
from pipeline.errors import ConfigError
from pipeline.paramsfile import load_params, parse_params
from pipeline.userfiles import parse_yaml

METHODS = ("cow", "vlmap", "cf", "orion")
NAMES = {"cow": "CoW", "vlmap": "VLMap", "cf": "CF", "orion": "ORION"}
KINDS = ("corrective", "descriptive", "landmark", "procedural")  # the single feedback kinds, Table I's order
SETTINGS = ("none", "yesno", *KINDS, "mixed")
METRICS = ("SR", "SPL", "SIT")
_KEY = {"SR": "success", "SPL": "spl", "SIT": "sit"}

#: the ORION paper, Table I (none ... procedural) and Table II (mixed): (SR, SPL, SIT) percent
PAPER = {
    "cow": {"none": (15.4, 8.4, 15.4), "yesno": (36.8, 24.2, 35.8), "corrective": (38.5, 21.6, 29.0),
            "descriptive": (53.5, 22.4, 33.2), "landmark": (43.9, 21.3, 30.2), "procedural": (59.0, 22.5, 32.8),
            "mixed": (62.4, 33.7, 36.2)},
    "vlmap": {"none": (23.9, 20.3, 23.9), "yesno": (41.8, 30.8, 31.2), "corrective": (43.6, 32.6, 35.2),
              "descriptive": (44.4, 31.5, 35.8), "landmark": (53.3, 35.8, 39.0), "procedural": (67.5, 52.7, 44.1),
              "mixed": (71.8, 54.8, 48.0)},
    "cf": {"none": (21.3, 13.7, 21.3), "yesno": (47.9, 25.6, 31.1), "corrective": (52.1, 37.5, 36.5),
           "descriptive": (47.0, 33.5, 34.1), "landmark": (59.9, 40.1, 40.6), "procedural": (68.4, 49.4, 39.3),
           "mixed": (73.5, 52.3, 44.2)},
    "orion": {"none": (28.2, 24.9, 28.2), "yesno": (54.2, 35.5, 37.8), "corrective": (59.0, 34.2, 39.1),
              "descriptive": (63.7, 37.4, 44.2), "landmark": (69.5, 40.1, 46.8), "procedural": (80.3, 51.1, 52.8),
              "mixed": (83.8, 56.6, 53.5)},
}


#: the ORION paper, Table II's lower part: ORION and its ablations in the mixed setting, (SR, SPL, SIT) percent
PAPER_ABLATIONS = {"orion": (83.8, 56.6, 53.5), "orion_wo_mem": (81.2, 54.8, 51.2), "orion_wo_exp": (75.9, 51.6, 49.7),
                   "orion_wo_det": (72.5, 47.7, 42.2), "orion_wo_map": (69.2, 37.5, 41.3)}
ABLATION_NAMES = {"orion": "ORION", "orion_wo_mem": "w/o mem", "orion_wo_exp": "w/o exp", "orion_wo_det": "w/o det",
                  "orion_wo_map": "w/o map"}


#: HM3D's navigable floor a scene: 112.5k m2 over its 1,000 scenes (Ramakrishnan et al., NeurIPS 2021 Datasets and
#: Benchmarks, abstract); the paper's 10 scenes are from its validation split
HM3D_NAVIGABLE_M2 = 112.5
#: apartments of this many rooms have 72-113 m2 of navigable floor, mean 96.0 (measured on the check's 10 scenes: the
#: report prints each); the simulator's default 6-7 rooms have 47-66 m2, half of an HM3D scene
HM3D_ROOMS = 10
#: the paper ends an episode only on success or after I_max questions (its reference code, navchat, has no step
#: budget); on the 10 HM3D-sized scenes it ends none of 16,240 episodes (the longest takes 2,384 steps): it would stop
#: a runaway, not a search (the 7 it once ended were walks into a wall the world and the planners disagreed about)
MAX_STEPS = 4000
#: the check's own scene set: names and ``simulate.seed`` no test, demo or other benchmark uses (``--prefix``,
#: ``--seed`` choose another, fresh one)
PREFIX, SEED = "findings", 2027


def navigable_areas(ws, params) -> dict[str, float]:
    """m2 of navigable floor of each scene, from its reconstruction."""
    from pipeline.scene import Scene

    out = {}
    for name in params.scenes:
        scene = Scene(ws, params, name, STAGES)
        out[name] = round(float(np.count_nonzero(scene.navigable)) * scene.grid.cell_size_m ** 2, 1)
    return out


def workspace_of(root: Path, scenes: list[str]):
    """``(workspace, params)`` of the check's workspace at ``root`` when it holds every scene of ``scenes`` (the params
    narrowed to them), else None."""
    from pipeline.paths import Workspace

    path = root / "params.yaml"
    if not scenes or not path.is_file():
        return None
    params = load_params(path)
    if not set(scenes) <= set(params.scenes):
        return None
    params = params.model_copy(update={"scenes": {k: v for k, v in params.scenes.items() if k in scenes}})
    return Workspace.resolve(path, data_dir=root / "data", manifests_dir=root / "manifests"), params


def paper_tables() -> dict[str, np.ndarray]:
    """metric -> (4 methods, 7 settings) array of the paper's values."""
    return {m: np.array([[PAPER[meth][s][k] for s in SETTINGS] for meth in METHODS]) for k, m in enumerate(METRICS)}


class Cells:
    """Per (scene, goal) sums and counts of each metric in each (method, setting) cell, for bootstrap draws; only the
    episodes of ``methods`` in ``settings`` count (the goals are those they cover)."""

    def __init__(self, episodes: list[dict], methods: tuple[str, ...] = METHODS, settings: tuple[str, ...] = SETTINGS):
        episodes = [e for e in episodes if e["method"] in methods and e["feedback"] in settings]
        self.methods, self.settings = methods, settings
        self.goals = sorted({(e["scene"], e["goal"]) for e in episodes})
        gi = {g: i for i, g in enumerate(self.goals)}
        shape = (len(self.goals), len(methods), len(settings))
        self.sums = {m: np.zeros(shape) for m in METRICS}
        self.counts = np.zeros(shape)
        for e in episodes:
            idx = (gi[(e["scene"], e["goal"])], methods.index(e["method"]), settings.index(e["feedback"]))
            self.counts[idx] += 1
            for m in METRICS:
                self.sums[m][idx] += float(e[_KEY[m]])

    def tables(self, weights: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """metric -> (methods, settings) percent, goals weighted by ``weights`` (None: each once)."""
        w = np.ones(len(self.goals)) if weights is None else weights
        n = np.tensordot(w, self.counts, axes=1)
        return {m: 100.0 * np.tensordot(w, self.sums[m], axes=1) / np.maximum(n, 1) for m in METRICS}


def figures(t: dict[str, np.ndarray], paper: dict[str, np.ndarray]) -> dict[str, float]:
    """Every number the check reports, from one set of tables ``t`` (so each gets a bootstrap interval)."""
    sr = t["SR"]
    col = {s: sr[:, SETTINGS.index(s)] for s in SETTINGS}
    gain = {k: col[k] - col["yesno"] for k in KINDS}
    out: dict[str, float] = {}
    for m in METRICS:
        out[f"{m} spearman"] = float(spearmanr(t[m].ravel(), paper[m].ravel())[0])
        out[f"{m} mean |d|"] = float(np.mean(np.abs(t[m] - paper[m])))
    for i, meth in enumerate(METHODS):
        for k in KINDS:
            out[f"gain {k} {meth}"] = float(gain[k][i])
        best_single = max(col[k][i] for k in KINDS)
        out[f"mixed - best single {meth}"] = float(col["mixed"][i] - best_single)
        out[f"procedural - next best {meth}"] = float(gain["procedural"][i] - max(gain[k][i] for k in KINDS[:3]))
        out[f"mean SR with feedback {meth}"] = float(np.mean([col[s][i] for s in SETTINGS[1:]]))
    det = [METHODS.index(x) for x in ("cow", "orion")]
    maps = [METHODS.index(x) for x in ("vlmap", "cf")]
    out["descriptive: detection min - map max"] = float(min(gain["descriptive"][det]) - max(gain["descriptive"][maps]))
    mean_gain = {k: float(np.mean(gain[k])) for k in KINDS}
    for k in KINDS:
        out[f"mean gain {k}"] = mean_gain[k]
    out["corrective - next least (mean gains)"] = mean_gain["corrective"] - min(mean_gain[k] for k in KINDS[1:])
    others = [float(np.mean([col[s][i] for s in SETTINGS[1:]])) for i in range(1, len(METHODS))]
    out["CoW - weakest other (mean SR with feedback)"] = out["mean SR with feedback cow"] - min(others)
    o, v = METHODS.index("orion"), METHODS.index("vlmap")
    out["ORION - VLMap SR (mean over settings)"] = float(np.mean(sr[o] - sr[v]))
    out["ORION - VLMap SPL (mean over settings)"] = float(np.mean(t["SPL"][o] - t["SPL"][v]))
    return out


def findings(f: dict[str, float]) -> list[tuple[str, bool, str]]:
    """The paper's findings (1)-(6) as (statement, holds, figures) on point estimates ``f``."""
    g = lambda k, m: f[f"gain {k} {m}"]  # noqa: E731
    per = lambda k: ", ".join(f"{NAMES[m]} {g(k, m):+.1f}" for m in METHODS)  # noqa: E731
    return [
        ("(1) procedural feedback brings the largest gain over yes/no for every method",
         all(f[f"procedural - next best {m}"] > 0 for m in METHODS),
         f"procedural gains {per('procedural')}; margin over the next kind "
         + ", ".join(f"{NAMES[m]} {f[f'procedural - next best {m}']:+.1f}" for m in METHODS)),
        ("(2) landmark feedback boosts every method (gain over yes/no > 0)",
         all(g("landmark", m) > 0 for m in METHODS), f"landmark gains {per('landmark')}"),
        ("(3) descriptive feedback helps the ego-view detection methods (CoW, ORION) more than the map-based ones",
         f["descriptive: detection min - map max"] > 0,
         f"descriptive gains {per('descriptive')}; min(CoW, ORION) - max(VLMap, CF) "
         f"{f['descriptive: detection min - map max']:+.1f}"),
        ("(4) corrective feedback brings the least improvement (mean gain over methods)",
         f["corrective - next least (mean gains)"] < 0,
         "mean gains " + ", ".join(f"{k} {f[f'mean gain {k}']:+.1f}" for k in KINDS)),
        ("(5) mixed feedback beats every single feedback, for every method",
         all(f[f"mixed - best single {m}"] > 0 for m in METHODS),
         "mixed - best single " + ", ".join(f"{NAMES[m]} {f[f'mixed - best single {m}']:+.1f}" for m in METHODS)),
        ("(6) CoW is the weakest method with feedback (mean SR over the settings with interaction)",
         f["CoW - weakest other (mean SR with feedback)"] < 0,
         ", ".join(f"{NAMES[m]} {f[f'mean SR with feedback {m}']:.1f}" for m in METHODS)),
    ]


def resample(rng: np.random.Generator, n: int) -> np.ndarray:
    """Bootstrap weights of ``n`` goals: how often each is drawn when ``n`` are drawn with replacement."""
    return np.bincount(rng.integers(0, n, n), minlength=n).astype(np.float64)


def bootstrap(cells: Cells, paper: dict[str, np.ndarray], draws: int, seed: int = 0) -> dict[str, tuple[float, float]]:
    """95 % percentile intervals of every figure, goals resampled with replacement."""
    rng = np.random.default_rng(seed)
    samples: dict[str, list[float]] = {}
    for _ in range(draws):
        w = resample(rng, len(cells.goals))
        for k, v in figures(cells.tables(w), paper).items():
            samples.setdefault(k, []).append(v)
    return {k: (float(np.nanpercentile(v, 2.5)), float(np.nanpercentile(v, 97.5))) for k, v in samples.items()}


def print_report(res: dict, cells: Cells, draws: int) -> dict:
    paper = paper_tables()
    t = cells.tables()
    f = figures(t, paper)
    ci = bootstrap(cells, paper, draws)
    run = res["run"]
    print(f"scenes {len(run['scenes'])} ({', '.join(run['scenes'])}), goals {len(cells.goals)}, seeds "
          f"{len(run['seeds'])}, episodes per cell {int(cells.counts.sum(axis=0).min())}")
    maps = sorted({v["kind"] for enc in run["encoders"].values() for v in enc.values()})
    print("maps: " + " | ".join(maps))
    print("detection: " + " | ".join(sorted(set(run["detection"].values()))))
    capped = sum(e.get("end") == "step budget" for e in res["episodes"])
    print(f"episodes ended by the step budget (eval.max_steps, a bound the paper has not): {capped} of "
          f"{len(res['episodes'])}")
    if "stale" not in run:
        print("artifacts evaluated: not recorded (a results.json from before run.artifacts / run.stale)")
    elif run["stale"]:
        print("evaluated on stale artifacts (run.stale; rerun them with zipon run): " + stale_text(run["stale"]))
    for m in METRICS:
        print(f"\n{m} %  (ours / paper)")
        print(f"{'':6}" + "".join(f"{s:>14}" for s in SETTINGS))
        for i, meth in enumerate(METHODS):
            print(f"{NAMES[meth]:6}" + "".join(f"{t[m][i, j]:7.1f}/{paper[m][i, j]:<6.1f}" for j in range(len(SETTINGS))))
    print()
    iv = lambda k: f"[{ci[k][0]:.2f}, {ci[k][1]:.2f}]"  # noqa: E731
    for m in METRICS:
        print(f"{m}: Spearman rho {f[f'{m} spearman']:.2f} {iv(f'{m} spearman')}, mean |d| "
              f"{f[f'{m} mean |d|']:.1f} points {iv(f'{m} mean |d|')}  (targets for SR: rho >= 0.8, mean |d| <= 8)")
    print(f"ORION - VLMap, mean over settings: SR {f['ORION - VLMap SR (mean over settings)']:+.1f} "
          f"{iv('ORION - VLMap SR (mean over settings)')}, SPL {f['ORION - VLMap SPL (mean over settings)']:+.1f} "
          f"{iv('ORION - VLMap SPL (mean over settings)')}  (paper: SR +11.5, SPL +2.0)")
    print()
    out = []
    for text, holds, detail in findings(f):
        print(f"{'HOLDS   ' if holds else 'DOES NOT'} {text}\n         {detail}")
        out.append({"finding": text, "holds": holds, "detail": detail})
    keys = [k for k in f if k.startswith(("gain ", "mixed - ", "procedural - ", "descriptive:", "corrective - ",
                                          "CoW - "))]
    print(f"\n95 % intervals (bootstrap over goals, {draws} draws):")
    for k in keys:
        print(f"  {k}: {f[k]:+.1f} {iv(k)}")
    return {"tables": {m: t[m].round(2).tolist() for m in METRICS}, "figures": f, "intervals": ci, "findings": out,
            "methods": list(METHODS), "settings": list(SETTINGS)}


#: what the check says it expected of each field of :class:`orion_eval.records.EpisodeOutcome` it reads
EXPECTED = {"scene": "a str", "goal": "a str", "method": "a str", "feedback": "a str", "seed": "an int",
            "success": "a bool", "spl": "a number in [0, 1]", "sit": "a number in [0, 1]"}


def episode_error(episodes) -> str | None:
    """What is wrong with the first episode of a results.json that the check cannot read (its index, the field and
    what was expected), None when every one is an :class:`~orion_eval.records.EpisodeOutcome`."""
    if not isinstance(episodes, list):
        return f"'episodes' is a {type(episodes).__name__}, expected a list of episode records"
    for i, e in enumerate(episodes):
        if not isinstance(e, dict):
            return f"episode {i} is a {type(e).__name__}, expected an object"
        try:
            EpisodeOutcome.model_validate(e)
        except ValidationError as err:
            name = str(err.errors()[0]["loc"][0])
            return (f"episode {i} ({e.get('scene')}/{e.get('goal')}): field {name!r} is {e.get(name)!r}, "
                    f"expected {EXPECTED[name]}")
    return None


def scene_set(params, seeds: int, areas: dict[str, float] | None = None) -> dict:
    """What the JSON records of the scene set: its names' prefix, ``simulate.seed``, rooms and frames (from the
    workspace's params, so a report from ``--results`` records them too), the scenes and the evaluation's seeds."""
    sim = params.simulate
    scenes = list(params.scenes)
    prefixes = {name.rsplit("_", 1)[0] for name in scenes}
    rooms = sim.rooms_min if sim.rooms_min == sim.rooms_max else [sim.rooms_min, sim.rooms_max]
    out = {"prefix": prefixes.pop() if len(prefixes) == 1 else None, "seed": sim.seed, "rooms": rooms,
           "frames": sim.frames, "scenes": scenes, "seeds": seeds}
    if areas is not None:
        out["navigable_m2"] = areas
    return out


def drivers_report(episodes: list[dict], cells: Cells, stats: dict) -> dict:
    """What drives each effect (:mod:`findings_drivers`), printed, and the check's figures with the goals weighted to
    the paper's mix of goal types (a what-if beside the check: how much of the set's distance from the paper is its
    mix of goals)."""
    doc = driver_figures(episodes, stats, Cells)
    print_drivers(doc, NAMES)
    types = {g: r["type"] for g, r in stats["goals"].items()}
    f = figures(cells.tables(paper_mix_weights(cells.goals, types)), paper_tables())
    held = findings(f)
    doc["paper mix"] = {"figures": f, "findings": [{"finding": t, "holds": h} for t, h, _ in held]}
    print("\nthe same episodes with the goals weighted to the paper's mix of types (a what-if, not the check): SR "
          f"Spearman rho {f['SR spearman']:.2f}, mean |d| {f['SR mean |d|']:.1f}; findings "
          + ", ".join(f"({t.split(')')[0].lstrip('(')}) {'holds' if h else 'does not'}" for t, h, _ in held))
    return doc


def ablation_figures(episodes: list[dict], draws: int, seed: int = 0) -> dict:
    """ORION and its ablations in the mixed setting: ``{"rows": {method: (SR, SPL, SIT)}, "drops": {method: SR drop
    from ORION}, "intervals": {method: (lo, hi) of the drop}, "findings": [(text, holds, detail)]}``. The drops'
    95 % intervals come from a bootstrap over goals (each goal's episodes of every method resampled together)."""
    methods = tuple(m for m in PAPER_ABLATIONS if any(e["method"] == m and e["feedback"] == "mixed" for e in episodes))
    if "orion" not in methods or len(methods) < 2:
        raise ValueError("the ablation report needs ORION's and at least one ablation's mixed episodes")
    cells = Cells(episodes, methods, ("mixed",))
    t = np.stack([cells.tables()[k][:, 0] for k in METRICS], axis=1)  # (methods, metrics) percent
    rng = np.random.default_rng(seed)
    sr = np.array([cells.tables(resample(rng, len(cells.goals)))["SR"][:, 0] for _ in range(draws)])  # (draws, methods)
    drop_draws = sr[:, :1] - sr
    rows = {m: tuple(float(v) for v in t[j]) for j, m in enumerate(methods)}
    drops = {m: float(t[0, 0] - t[j, 0]) for j, m in enumerate(methods) if m != "orion"}
    intervals = {m: (float(np.percentile(drop_draws[:, j], 2.5)), float(np.percentile(drop_draws[:, j], 97.5)))
                 for j, m in enumerate(methods) if m != "orion"}
    per = ", ".join(f"{ABLATION_NAMES[m]} {d:+.1f}" for m, d in drops.items())
    out = [("(A1) every module taken away costs SR (ORION - ablation > 0)", all(d > 0 for d in drops.values()),
            f"SR drops {per}")]
    if "orion_wo_map" in drops:
        others = [d for m, d in drops.items() if m != "orion_wo_map"]
        out.append(("(A2) taking the map away costs the most", all(drops["orion_wo_map"] > d for d in others),
                    f"w/o map {drops['orion_wo_map']:+.1f}, the others' largest {max(others, default=float('nan')):+.1f}"))
    if "orion_wo_mem" in drops:
        others = [d for m, d in drops.items() if m != "orion_wo_mem"]
        out.append(("(A3) taking the memory away costs the least", all(drops["orion_wo_mem"] < d for d in others),
                    f"w/o mem {drops['orion_wo_mem']:+.1f}, the others' smallest {min(others, default=float('nan')):+.1f}"))
    return {"rows": rows, "drops": drops, "intervals": intervals, "findings": out}


def print_ablations(episodes: list[dict], draws: int) -> dict:
    a = ablation_figures(episodes, draws)
    print("\nORION's ablations, mixed feedback  (ours / paper, Table II lower part)")
    print(f"{'':10}" + "".join(f"{m:>14}" for m in METRICS) + f"{'SR drop':>16}")
    for m, row in a["rows"].items():
        paper = PAPER_ABLATIONS[m]
        drop = "" if m == "orion" else (f"{a['drops'][m]:+6.1f}/{PAPER_ABLATIONS['orion'][0] - paper[0]:<+5.1f}"
                                        f" [{a['intervals'][m][0]:.1f}, {a['intervals'][m][1]:.1f}]")
        print(f"{ABLATION_NAMES[m]:10}" + "".join(f"{v:7.1f}/{p:<6.1f}" for v, p in zip(row, paper)) + f"  {drop}")
    print()
    for text, holds, detail in a["findings"]:
        print(f"{'HOLDS   ' if holds else 'DOES NOT'} {text}\n         {detail}")
    return {"rows": a["rows"], "drops": a["drops"], "intervals": a["intervals"],
            "findings": [{"finding": t, "holds": h, "detail": d} for t, h, d in a["findings"]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workspace", type=Path, default=Path("/tmp/findings"), help="folder for the fresh scenes")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--rooms", type=int, default=HM3D_ROOMS, help="rooms of every apartment (the default sizes them "
                    "like the paper's HM3D scenes: see HM3D_NAVIGABLE_M2; 0: the simulator's default range)")
    ap.add_argument("--prefix", default=PREFIX, help="the scenes' names are <prefix>_00, <prefix>_01, ...: a fresh "
                    "prefix and --seed make a scene set the evaluator was never developed on (the JSON records both)")
    ap.add_argument("--seed", type=int, default=SEED, help="simulate.seed of the scene set (each scene's own seed "
                    "derives from it and the scene's name)")
    ap.add_argument("--build-only", action="store_true", help="build the scenes and stop (the evaluation's code is "
                    "no stage's: a later call evaluates them as built)")
    ap.add_argument("--frames", type=int, default=480, help="simulate.frames of the scenes")
    ap.add_argument("--max-steps", type=int, default=MAX_STEPS, help="eval.max_steps: a bound the paper's episodes "
                    "do not have (they end on success or after I_max questions); the report says if one reached it")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--workers", type=int, default=2, help="eval.workers: scenes evaluated in parallel processes "
                    "(each scene's episodes are the same whatever the count)")
    ap.add_argument("--boot", type=int, default=1000, help="bootstrap draws for the 95 %% intervals")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    ap.add_argument("--results", type=Path, default=None,
                    help="report on an earlier run's results.json instead of building and evaluating")
    ap.add_argument("--reuse-stale", action="store_true",
                    help="evaluate the scenes' stale artifacts as they are instead of rerunning their stages (the "
                         "build line names each stale stage and why)")
    ap.add_argument("--ablations", action="store_true",
                    help="also evaluate ORION's ablations in the mixed setting and compare them with the paper's")
    args = ap.parse_args()
    if args.results:
        try:
            res = json.loads(args.results.read_text())
            episodes = res["episodes"]
        except (OSError, ValueError, KeyError, TypeError) as err:
            ap.error(f"--results {args.results}: cannot be read as an evaluation's results.json "
                     f"({type(err).__name__}: {err}); expected the JSON `zipon eval` writes, with 'episodes'")
        wrong = episode_error(episodes)
        if wrong:
            ap.error(f"--results {args.results}: {wrong} (the episodes `zipon eval` writes)")
        mixed = {e.get("method") for e in episodes if e.get("feedback") == "mixed"}
        if args.ablations and ("orion" not in mixed or not mixed & set(PAPER_ABLATIONS) - {"orion"}):
            ap.error(f"--ablations: {args.results} holds no mixed episodes of ORION and of one of its ablations "
                     f"(found mixed episodes of {sorted(m for m in mixed if m)}); evaluate them with `zipon eval -f "
                     f"mixed -m orion -m orion_wo_map ...`")
        cells = Cells(episodes)
        doc = print_report(res, cells, args.boot)
        ws = workspace_of(args.workspace, res["run"].get("scenes") or [])
        if ws is not None:
            try:
                doc["drivers"] = drivers_report(episodes, cells, scene_statistics(*ws, STAGES))
            except ValueError as err:
                ap.error(f"--results {args.results} against --workspace {args.workspace}: {err}")
            doc["scene_set"] = scene_set(ws[1], len({e["seed"] for e in episodes}))
        else:
            print(f"\nwhat drives each effect: not computed ({args.workspace} holds no built workspace of these scenes; "
                  "name it with --workspace)")
        if args.ablations:
            doc["ablations"] = print_ablations(episodes, args.boot)
        if args.json:
            args.json.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
        return
    overrides = [f"eval.workers={args.workers}", f"eval.max_steps={args.max_steps}"]
    try:  # the options are checked as params before anything is built (a build of 10 scenes takes 20 minutes)
        if not args.prefix.isidentifier():
            raise ConfigError(f"--prefix {args.prefix!r}: a scene name's prefix must be letters, digits and underscores, "
                              "not starting with a digit")
        text = build_params(args.scenes, args.frames, args.prefix, args.seed, args.rooms or None)
        parse_params(parse_yaml(text, origin="the check's params"), origin="the check's params", overrides=overrides)
    except ConfigError as err:
        ap.error(f"{err}\n(set by --scenes, --rooms, --frames, --prefix, --seed, --workers and --max-steps)")
    ws = build(args.workspace, args.scenes, args.frames, prefix=args.prefix, seed=args.seed, bench="findings",
               rooms=args.rooms or None, reuse_stale=args.reuse_stale)
    if args.build_only:
        return
    params = load_params(ws.params_path, overrides)
    areas = navigable_areas(ws, params)
    emit(bench="findings", figure="navigable_m2", scenes=areas, mean=round(float(np.mean(list(areas.values()))), 1),
         hm3d_mean=HM3D_NAVIGABLE_M2)
    res = evaluate(ws, params, STAGES, args.workspace / "eval", scenes=list(params.scenes), methods=list(METHODS),
                   feedback=list(FEEDBACK_SETTINGS), seeds=list(range(args.seeds)), progress=False, report=False)
    emit(bench="findings", figure="run", episodes=res["run"]["episodes"], seconds=res["run"]["seconds"])
    doc = print_report(res, Cells(res["episodes"]), args.boot)
    doc["drivers"] = drivers_report(res["episodes"], Cells(res["episodes"]), scene_statistics(ws, params, STAGES))
    doc["scene_set"] = scene_set(params, args.seeds, areas)
    if args.ablations:
        abl = evaluate(ws, params, STAGES, args.workspace / "eval_ablations", scenes=list(params.scenes),
                       methods=[m for m in PAPER_ABLATIONS if m != "orion"], feedback=["mixed"],
                       seeds=list(range(args.seeds)), progress=False, report=False)
        emit(bench="findings", figure="ablations", episodes=abl["run"]["episodes"], seconds=abl["run"]["seconds"])
        doc["ablations"] = print_ablations(res["episodes"] + abl["episodes"], args.boot)
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
