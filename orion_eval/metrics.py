"""Aggregates of per-episode metrics (SR, SPL, SIT) and the Wilcoxon signed-rank test between methods.

Per episode (see :mod:`orion_eval.episode`): S, SPL = S * l / max(a, l), SIT = S / I. A cell of a table
(method x feedback setting, optionally per scene / goal) is the mean over its episodes of each seed,
then the mean over seeds (``std`` across seeds is reported beside it). Values are percentages
(0-100) as in the paper's tables. The success-by-turn curve is the share of episodes that succeed
within i Talk turns, i = 1..I_max (Fig. 4). Wilcoxon tests pair episodes between methods, over all
settings and within each setting (the paper's per-column test).

Episodes of a building (they carry ``cross_floor``) are also reported apart: ``by_floors`` is method -> 'same floor'
| 'cross floor' -> feedback -> cell (a goal on the start's floor, or on another one, reached over the stairs).
Results with no building episode have no ``by_floors``, as before buildings.
"""

from __future__ import annotations

from collections import defaultdict
from itertools import combinations

import numpy as np

METRICS = ("SR", "SPL", "SIT")
_KEY = {"SR": "success", "SPL": "spl", "SIT": "sit"}


def _cell(eps: list[dict]) -> dict:
    """Mean over seeds of the per-seed means (percent), with std over seeds and the episode count."""
    by_seed = defaultdict(list)
    for e in eps:
        by_seed[e["seed"]].append(e)
    out = {"episodes": len(eps)}
    for m in METRICS:
        per_seed = [100.0 * float(np.mean([float(e[_KEY[m]]) for e in es])) for _, es in sorted(by_seed.items())]
        out[m] = round(float(np.mean(per_seed)), 4) if per_seed else None
        out[f"{m}_std"] = round(float(np.std(per_seed)), 4) if per_seed else None
    return out


def group(episodes: list[dict], *keys: str) -> dict:
    """Nested dict keys[0] -> keys[1] -> ... -> cell."""
    buckets = defaultdict(list)
    for e in episodes:
        buckets[tuple(e[k] for k in keys)].append(e)
    out: dict = {}
    for k, eps in sorted(buckets.items()):
        node = out
        for part in k[:-1]:
            node = node.setdefault(part, {})
        node[k[-1]] = _cell(eps)
    return out


def success_by_turn(episodes: list[dict], max_turns: int) -> dict:
    """method -> feedback -> [share (percent) succeeded within i Talk turns for i = 1..max_turns]."""
    buckets = defaultdict(list)
    for e in episodes:
        buckets[(e["method"], e["feedback"])].append(e)
    out: dict = {}
    for (m, f), eps in sorted(buckets.items()):
        turns = np.array([e["talk_turns"] if e["success"] else np.inf for e in eps])
        out.setdefault(m, {})[f] = [round(100.0 * float(np.mean(turns <= i)), 4) for i in range(1, max_turns + 1)]
    return out


def wilcoxon_tests(episodes: list[dict], metric: str = "SR") -> list[dict]:
    """Two-sided Wilcoxon signed-rank tests between every pair of methods, paired per
    (scene, goal, feedback, seed) episode on ``metric``; ``p`` is None when all differences are zero."""
    from scipy.stats import wilcoxon

    key = _KEY[metric]
    table = defaultdict(dict)
    for e in episodes:
        table[e["method"]][(e["scene"], e["goal"], e["feedback"], e["seed"])] = float(e[key])
    out = []
    for a, b in combinations(sorted(table), 2):
        common = sorted(set(table[a]) & set(table[b]))
        x = np.array([table[a][k] for k in common])
        y = np.array([table[b][k] for k in common])
        diff = x - y
        rec = {"a": a, "b": b, "metric": metric, "pairs": len(common), "mean_a": round(float(x.mean() * 100), 4)
               if len(x) else None, "mean_b": round(float(y.mean() * 100), 4) if len(y) else None,
               "nonzero": int(np.count_nonzero(diff))}
        if np.count_nonzero(diff) == 0:
            rec.update(statistic=None, p=None)
        else:
            res = wilcoxon(x, y, zero_method="wilcox", alternative="two-sided")
            rec.update(statistic=float(res.statistic), p=float(res.pvalue))
        out.append(rec)
    return out


def wilcoxon_by_feedback(episodes: list[dict], metric: str = "SR") -> list[dict]:
    """:func:`wilcoxon_tests` within each feedback setting (the paper's per-column tests, Table I), each record
    with its ``feedback``."""
    by_fb = defaultdict(list)
    for e in episodes:
        by_fb[e["feedback"]].append(e)
    return [{"feedback": fb, **t} for fb, eps in by_fb.items() for t in wilcoxon_tests(eps, metric)]


def significantly_best(tests: list[dict], method: str, alpha: float = 0.05) -> set[str]:
    """Feedback settings where ``method`` beats every other method that is tested against it with p < ``alpha``
    (the paper's asterisk); ``tests`` from :func:`wilcoxon_by_feedback`. Upper bounds are left to the caller."""
    wins: dict[str, list[bool]] = defaultdict(list)
    for t in tests:
        if method not in (t["a"], t["b"]):
            continue
        mine, other = (t["mean_a"], t["mean_b"]) if t["a"] == method else (t["mean_b"], t["mean_a"])
        wins[t["feedback"]].append(t["p"] is not None and t["p"] < alpha and mine > other)
    return {fb for fb, w in wins.items() if w and all(w)}


#: how ``by_floors`` names an episode whose goal is on its start's floor, and one on another floor
FLOOR_GROUPS = {False: "same floor", True: "cross floor"}


def by_floors(episodes: list[dict]) -> dict | None:
    """method -> 'same floor' | 'cross floor' -> feedback -> cell, over the episodes of buildings (those with
    ``cross_floor``); None when there are none."""
    floored = [{**e, "floors": FLOOR_GROUPS[bool(e["cross_floor"])]} for e in episodes if "cross_floor" in e]
    return group(floored, "method", "floors", "feedback") if floored else None


def summarize(episodes: list[dict], *, methods, feedback, seeds, scenes, max_turns: int = 5) -> dict:
    """The results document: overall and per-scene / per-goal-type / per-goal tables, curves, tests; a building's
    episodes also by whether they cross floors (:func:`by_floors`)."""
    slim = [{k: v for k, v in e.items() if k != "log"} for e in episodes]
    floors = by_floors(slim)
    return {
        **({"by_floors": floors} if floors is not None else {}),
        "metrics": list(METRICS),
        "overall": group(slim, "method", "feedback"),
        "by_scene": group(slim, "scene", "method", "feedback"),
        "by_goal_type": group(slim, "goal_type", "method", "feedback"),
        "by_goal": group(slim, "scene", "goal", "method", "feedback"),
        "success_by_turn": success_by_turn(slim, max_turns),
        "wilcoxon": {m: wilcoxon_tests(slim, m) for m in METRICS},
        "wilcoxon_by_feedback": {m: wilcoxon_by_feedback(slim, m) for m in METRICS},
        "episodes": slim,
    }
