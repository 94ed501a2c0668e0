"""The evaluation report: ``results.json`` -> ``report.html`` (+ one page per scene), jinja2 templates, autoescaped.

- Table I: rows = methods, column groups = feedback settings, each with SR / SPL / SIT (percent, mean
  over seeds) with its 95 % confidence interval and the cell's episode count N. Bold = best per column
  among the methods that are not an upper bound (the GT route follower 'human' is shown, never bold).
- Table II: the same per goal type (big / small / ambiguous) for the setting with all feedback
  ("mixed" when evaluated, else the last setting).
- Buildings: when a building was evaluated, the episodes whose goal is on the start's floor ("same floor") and
  those whose goal is on another floor, reached over the stairs ("cross floor"), each as Table I
  (``results['by_floors']``).
- Fig. 4: success rate within i Talk turns, one line per method, one panel per feedback setting
  (``success_by_turn.png``); SR per setting as bars (``sr_by_feedback.png``). One colour per method,
  the same in every run (:func:`method_color`); legends sit beside the axes, never over data.
- Wilcoxon signed-rank tests (SR) between methods: over all settings, and within each setting between the
  methods that are not an upper bound (p per pair and setting); * marks an SR that beats every other such
  method significantly (p < 0.05), as the paper's Table I does.
- ``scenes/<scene>.html`` per scene: its table, pictures (floor plan, goals, routes, map queries with colour
  bars) and an episode browser (each method's path on the map with its dialogue) when the workspace is given.

Confidence intervals: SR (a proportion) uses the Wilson score interval; SPL and SIT use Student's t
on the per-episode values (both over the cell's N episodes, pooled across seeds).
"""

from __future__ import annotations

import gzip
import hashlib
import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from orion_eval.agents import AGENTS
from orion_eval.metrics import FLOOR_GROUPS, METRICS

FB_NAMES = {"none": "No interaction", "yesno": "Yes/No", "corrective": "Corrective", "descriptive": "Descriptive",
            "landmark": "Landmark", "procedural": "Procedural", "mixed": "Mixed"}
_KEY = {"SR": "success", "SPL": "spl", "SIT": "sit"}
DEFINITIONS = {
    "SR": "success rate: share of episodes that end with the user confirming the goal (the agent within the "
          "success distance, the goal in view and in line of sight).",
    "SPL": "success weighted by path length: S · l / max(a, l), with l the geodesic length of the reference route "
           "and a the length the agent travelled.",
    "SIT": "success weighted by interaction turns: S / I, with I ≥ 1 the number of Talk turns of the episode.",
    "N": "episodes in the cell (goals × seeds); each value is the mean over seeds of the per-seed means, in percent.",
    "95 % CI": "Wilson score interval for SR, Student's t interval for SPL and SIT, over the cell's episodes.",
    "*": "SR significantly above every other method that is not an upper bound in that setting (two-sided Wilcoxon "
         "signed-rank test on the paired episodes, p < 0.05).",
}
EPISODES_PER_SCENE = 6  # the episode browser shows at most this many runs per scene


def method_name(m: str) -> str:
    """How tables and figures name method ``m``: its agent's ``label``, else the name itself."""
    return getattr(AGENTS.get(m), "label", "") or m


def is_upper_bound(m: str) -> bool:
    """Whether ``m`` follows the ground truth (shown for reference, never "best")."""
    return bool(getattr(AGENTS.get(m), "upper_bound", False))


def method_color(m: str) -> str:
    """The method's fixed colour (its agent's ``colour``, matplotlib tab10 hues); any other name gets a colour
    derived from its text (stable across runs)."""
    colour = getattr(AGENTS.get(m), "colour", "")
    if colour:
        return colour
    h = int(hashlib.blake2b(m.encode(), digest_size=4).hexdigest(), 16)
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((h % 360) / 360.0, 0.65, 0.75)
    return f"#{int(r * 255):02x}{int(g * 255):02x}{int(b * 255):02x}"


# ----------------------------------------------------------------------------- statistics

def confidence_interval(values: list[float], metric: str) -> tuple[float, float] | None:
    """95 % interval in percent of the mean of ``values`` (per-episode S, SPL or SIT in [0, 1])."""
    n = len(values)
    if n == 0:
        return None
    z = 1.959963984540054
    if metric == "SR":
        p = float(np.mean(values))
        den = 1 + z * z / n
        centre = (p + z * z / (2 * n)) / den
        half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
        lo, hi = centre - half, centre + half
    else:
        from scipy.stats import t

        m = float(np.mean(values))
        half = float(t.ppf(0.975, n - 1) * np.std(values, ddof=1) / math.sqrt(n)) if n > 1 else 1.0
        lo, hi = m - half, m + half
    return round(100 * max(lo, 0.0), 1), round(100 * min(hi, 1.0), 1)


def cell_intervals(episodes: list[dict], *keys: str) -> dict:
    """keys -> {metric: (lo, hi)} for every cell (same nesting as :func:`orion_eval.metrics.group`)."""
    buckets = defaultdict(list)
    for e in episodes:
        buckets[tuple(e[k] for k in keys)].append(e)
    out: dict = {}
    for k, eps in buckets.items():
        node = out
        for part in k[:-1]:
            node = node.setdefault(part, {})
        node[k[-1]] = {m: confidence_interval([float(e[_KEY[m]]) for e in eps], m) for m in METRICS}
    return out


def _table(cells: dict, cis: dict, methods: list[str], columns: list[str], column_names: dict,
           stars: set[tuple[str, str]] = frozenset()) -> dict:
    """The data a results table template needs; bold = best per column and metric among non-upper-bound methods;
    ``stars`` = (method, column) whose SR beats every other contender significantly (Wilcoxon, p < 0.05)."""
    contenders = [m for m in methods if not is_upper_bound(m)]
    best = {}
    for c in columns:
        for m in METRICS:
            vals = [cells.get(me, {}).get(c, {}).get(m) for me in contenders]
            vals = [v for v in vals if v is not None]
            best[(c, m)] = max(vals) if vals and max(vals) > 0 else None
    rows = []
    for me in methods:
        groups = []
        for c in columns:
            cell = cells.get(me, {}).get(c, {})
            ci = cis.get(me, {}).get(c, {})
            groups.append({"n": cell.get("episodes"), "metrics": [
                {"value": cell.get(m), "ci": ci.get(m), "star": m == "SR" and (me, c) in stars,
                 "bold": not is_upper_bound(me) and cell.get(m) is not None and cell.get(m) == best[(c, m)]}
                for m in METRICS]})
        rows.append({"method": me, "name": method_name(me), "color": method_color(me),
                     "upper": is_upper_bound(me), "groups": groups})
    return {"columns": [column_names.get(c, c) for c in columns], "metrics": list(METRICS), "rows": rows}


# ----------------------------------------------------------------------------- figures

def _legend_below(fig, ax_or_axes, methods) -> None:
    handles, labels = [], []
    import matplotlib.patches as mpatches

    for me in methods:
        handles.append(mpatches.Patch(color=method_color(me)))
        labels.append(method_name(me))
    fig.legend(handles, labels, loc="lower center", ncol=min(len(methods), 6), fontsize=8, frameon=False)


def plot_success_by_turn(results: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sbt = results["success_by_turn"]
    fbs, methods = results["run"]["feedback"], results["run"]["methods"]
    n = len(fbs)
    cols = min(4, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows + 0.5), squeeze=False, sharey=True)
    for k, fb in enumerate(fbs):
        ax = axes[k // cols][k % cols]
        for me in methods:
            ys = sbt.get(me, {}).get(fb)
            if ys:
                ax.plot(range(1, len(ys) + 1), ys, marker="o", color=method_color(me),
                        linestyle="--" if is_upper_bound(me) else "-", label=method_name(me))
        ax.set_title(FB_NAMES.get(fb, fb), fontsize=10)
        ax.set_xlabel("interaction turns")
        ax.set_ylim(0, 100)
        ax.grid(alpha=0.3)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].axis("off")
    for r in range(rows):
        axes[r][0].set_ylabel("success rate (%)")
    fig.tight_layout(rect=(0, 0.5 / (2.6 * rows + 0.5), 1, 1))
    _legend_below(fig, axes, methods)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_sr_by_feedback(results: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods, fbs = results["run"]["methods"], results["run"]["feedback"]
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(fbs)), 3.4))
    w = 0.8 / max(1, len(methods))
    for i, me in enumerate(methods):
        ys = [results["overall"].get(me, {}).get(fb, {}).get("SR") or 0 for fb in fbs]
        ax.bar(np.arange(len(fbs)) + i * w, ys, w, color=method_color(me), label=method_name(me),
               hatch="//" if is_upper_bound(me) else None, edgecolor="white")
    ax.set_xticks(np.arange(len(fbs)) + w * (len(methods) - 1) / 2)
    ax.set_xticklabels([FB_NAMES.get(f, f) for f in fbs], fontsize=8)
    ax.set_ylabel("SR (%)")
    ax.set_ylim(0, 100)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    _legend_below(fig, ax, methods)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- pages

def _env():
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(loader=PackageLoader("orion_eval", "templates"), autoescape=select_autoescape(["html"]),
                      undefined=StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters["pct"] = lambda v: "–" if v is None else f"{v:.1f}"
    env.filters["pval"] = lambda p: "–" if p is None else f"{p:.3g}"
    return env


def stale_text(stale: dict[str, str]) -> str:
    """results.json's ``run.stale`` (``{"scene/stage": why}``) on one line, for the report and the findings check."""
    return "; ".join(f"{k} ({why})" for k, why in stale.items())


def run_notes(run: dict) -> list[str]:
    """Lines under the report's title saying what the maps and detections were built with (one line per fact;
    the place for the perception model's label)."""
    notes = []
    diag = any(v.get("diagnostic") for enc in run.get("encoders", {}).values() for v in enc.values())
    if diag:
        notes.append("Maps built with the diagnostic oracle encoder (ground truth), not a perception model.")
    kinds = {(which, v.get("kind")) for enc in run.get("encoders", {}).values() for which, v in enc.items()
             if v.get("kind") and not v.get("diagnostic")}
    notes += [f"{which} built with {kind}." for which, kind in sorted(kinds)]
    notes += [f"Detection (cow, orion): {kind}." for kind in sorted(set(run.get("detection", {}).values()))]
    if run.get("stale"):
        notes.append("Evaluated as built, although they lag their code, params or inputs (rerun them with zipon run): "
                     + stale_text(run["stale"]) + ".")
    from orion_eval.agents import AGENTS

    mods = [f"{AGENTS[m].label}: {AGENTS[m].modules.describe()}" for m in run.get("methods", [])
            if m in AGENTS and getattr(AGENTS[m], "modules", None) is not None]
    if mods:
        notes.append("One controller for every method, each with its own modules (" + "; ".join(mods) + "); the "
                     "modules' error profiles come from published figures, none was set from these results.")
    return notes


def setting_tests(results: dict, methods: list[str], fbs: list[str]) -> tuple[set[tuple[str, str]], dict]:
    """From the per-setting Wilcoxon tests (SR) between the contenders (no upper bound): the (method, setting)
    cells that beat every other contender significantly, and the table of p values (pair rows x settings)."""
    from orion_eval.metrics import significantly_best

    contenders = [m for m in methods if not is_upper_bound(m)]
    tests = [t for t in results.get("wilcoxon_by_feedback", {}).get("SR", [])
             if t["a"] in contenders and t["b"] in contenders]
    stars = {(m, fb) for m in contenders for fb in significantly_best(tests, m)}
    rows: dict[tuple[str, str], dict] = {}
    for t in tests:
        rows.setdefault((t["a"], t["b"]), {})[t["feedback"]] = t
    table = {"settings": [FB_NAMES.get(f, f) for f in fbs],
             "rows": [{"pair": f"{method_name(a)} vs {method_name(b)}",
                       "cells": [rows[(a, b)].get(fb) for fb in fbs]} for a, b in sorted(rows)]}
    return stars, table


def write_report(results: dict, out_dir: Path, *, ws=None, params=None) -> Path:
    """Write ``report.html``, its figures and ``scenes/<scene>.html`` into ``out_dir``; returns the report's path.

    With the workspace ``ws`` and ``params``, scene pages also get pictures and the episode browser.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run = results["run"]
    methods, fbs = run["methods"], run["feedback"]
    episodes = results.get("episodes", [])
    plot_success_by_turn(results, out_dir / "success_by_turn.png")
    plot_sr_by_feedback(results, out_dir / "sr_by_feedback.png")
    setting = "mixed" if "mixed" in fbs else fbs[-1]
    types = [t for t in ("big", "small", "ambiguous") if t in results["by_goal_type"]]
    by_type = {me: {t: results["by_goal_type"][t].get(me, {}).get(setting, {}) for t in types} for me in methods}
    ci_type = cell_intervals([e for e in episodes if e["feedback"] == setting], "method", "goal_type")
    env = _env()
    scenes = [s for s in run["scenes"] if s in results["by_scene"]]
    ci_scene = cell_intervals(episodes, "scene", "method", "feedback")
    legend = [{"name": method_name(m), "color": method_color(m), "upper": is_upper_bound(m)} for m in methods]
    stars, per_setting = setting_tests(results, methods, fbs)
    common = {"fb_names": FB_NAMES, "definitions": DEFINITIONS, "legend": legend, "run": run}
    (out_dir / "scenes").mkdir(exist_ok=True)
    for s in scenes:
        table = _table(results["by_scene"][s], ci_scene.get(s, {}), methods, fbs, FB_NAMES)
        pictures, browser = [], []
        if ws is not None and params is not None:
            pictures = scene_pictures(ws, params, s, out_dir / "scenes" / s)
            browser = episode_browser(ws, s, out_dir, setting, methods, min(run["seeds"]))
        page = env.get_template("scene.html").render(scene=s, table=table, pictures=pictures, browser=browser,
                                                    setting=FB_NAMES.get(setting, setting), **common)
        (out_dir / "scenes" / f"{s}.html").write_text(page)
    page = env.get_template("report.html").render(
        notes=run_notes(run), floor_tables=floor_tables(results, episodes, methods, fbs),
        table1=_table(results["overall"], cell_intervals(episodes, "method", "feedback"), methods, fbs, FB_NAMES,
                      stars),
        setting_tests=per_setting,
        table2=_table(by_type, ci_type, methods, types, {t: t.capitalize() for t in types}),
        setting=FB_NAMES.get(setting, setting), tests=results["wilcoxon"]["SR"], names={m: method_name(m) for m in methods},
        scenes=[{"name": s, "href": f"scenes/{s}.html",
                 "episodes": sum(1 for e in episodes if e["scene"] == s)} for s in scenes],
        **common)
    path = out_dir / "report.html"
    path.write_text(page)
    return path


def floor_tables(results: dict, episodes: list[dict], methods: list[str], fbs: list[str]) -> list[dict]:
    """The buildings' episodes apart (``results['by_floors']``): one table per 'same floor' / 'cross floor', methods x
    feedback settings; none when no building was evaluated."""
    cells = results.get("by_floors")
    if not cells:
        return []
    floored = [{**e, "floors": FLOOR_GROUPS[bool(e["cross_floor"])]} for e in episodes if "cross_floor" in e]
    cis = cell_intervals(floored, "floors", "method", "feedback")
    out = []
    for kind in FLOOR_GROUPS.values():
        per_method = {m: cells.get(m, {}).get(kind, {}) for m in methods}
        if any(per_method.values()):
            out.append({"kind": kind, "episodes": sum(1 for e in floored if e["floors"] == kind),
                        "table": _table(per_method, cis.get(kind, {}), methods, fbs, FB_NAMES)})
    return out


def scene_pictures(ws, params, scene: str, folder: Path) -> list[dict]:
    """Floor plan (simulated scenes), goals, routes and two map queries of ``scene`` as PNGs in ``folder``;
    returns ``[{src, caption}]`` with paths relative to the report's ``scenes/`` folder."""
    art = {n: ws.artifact(n, scene) for n in ("frames", "recon", "vlmap", "cfmap", "goals", "routes")}
    out = []
    folder.mkdir(parents=True, exist_ok=True)

    def add(path: Path, caption: str) -> None:
        out.append({"src": f"{scene}/{path.name}", "caption": caption})

    if art["frames"].exists():
        from pipeline.frames import FrameStore

        gt = FrameStore(art["frames"]).ground_truth
        if gt is not None:
            from pipeline.sim.topdown import render_scene_png

            plans = gt.all_floors
            for k, floor in enumerate(plans):  # a building's ground truth: one plan per floor
                add(render_scene_png(gt, folder / ("plan.png" if len(plans) == 1 else f"plan_floor{k}.png"), floor=k),
                    "ground-truth floor plan" + (f" of {floor.name}" if len(plans) > 1 else ""))
    if not (art["recon"].exists() and art["goals"].exists()):
        return out
    from pipeline.goals.render import render_goals
    from pipeline.recon import Recon

    floors = Recon(art["recon"]).floors
    for k, floor in enumerate(floors):  # a building: each floor's goals and route legs on its own map
        tag, on = (f"_floor{k}", f" on {floor.name}") if len(floors) > 1 else ("", "")
        add(render_goals(art["recon"], art["goals"], None, "goals", folder / f"goals{tag}.png", floor=k),
            f"goals{on} (numbered; names in the legend) and landmark links")
        if art["routes"].exists():
            add(render_goals(art["recon"], art["goals"], art["routes"], "routes", folder / f"routes{tag}.png",
                             floor=k), f"verified routes{on} from their start poses")
    from pipeline.goals.store import Goals
    from pipeline.maps.query import open_query
    from pipeline.maps.render import render_query

    goals = Goals(art["goals"])
    # the first two goal classes, each queried on the floor of its first goal
    asked: dict[str, int] = {}
    for g in goals.goals:
        asked.setdefault(goals.objects[g.object_keys[0]].cls, g.floor)
    for which, (cls, k) in zip(("vlmap", "cfmap"), list(asked.items())[:2]):
        if art[which].exists():
            result = open_query(art[which], params, recon_path=art["recon"], frames_path=art["frames"],
                                floor=k).query(cls)
            tag, on = (f"_floor{k}", f" on {floors[k].name}") if len(floors) > 1 else ("", "")
            add(render_query(result, folder / f"query_{which}_{cls.replace(' ', '_')}{tag}.png"),
                f"{which} query '{cls}'{on}: heatmap and candidates")
    return out


def episode_browser(ws, scene: str, out_dir: Path, setting: str, methods: list[str], seed: int) -> list[dict]:
    """Each method's episode of the scene's first goal (``seed``, ``setting``) from the episode logs: its path on
    the map and its dialogue."""
    log = Path(out_dir) / "episodes" / f"{scene}.episodes.jsonl.gz"
    if not log.is_file():
        return []
    picked: dict[str, dict] = {}
    with gzip.open(log, "rt") as f:
        for line in f:
            e = json.loads(line)
            if e["feedback"] == setting and e["seed"] == seed and e["method"] not in picked:
                picked[e["method"]] = e
    chosen = [picked[m] for m in methods if m in picked][:EPISODES_PER_SCENE]
    if not chosen or not ws.artifact("goals", scene).exists():
        return []
    from pipeline.goals.render import render_episodes

    folder = Path(out_dir) / "scenes" / scene
    pngs = render_episodes(ws.artifact("recon", scene), ws.artifact("goals", scene),
                           [(e["goal"], e["log"]["poses"], method_color(e["method"]), e["log"].get("floors"))
                            for e in chosen],
                           [folder / f"episode_{e['method']}.png" for e in chosen])
    return [{"src": f"{scene}/{p.name}", "method": method_name(e["method"]), "color": method_color(e["method"]),
             "goal": e["goal"], "episode": e["episode"], "success": e["success"], "end": e["end"],
             "talk_turns": e["talk_turns"], "travelled_m": e["travelled_m"], "instruction": e["log"]["instruction"],
             "dialogue": e["log"]["dialogue"]} for e, p in zip(chosen, pngs)]
