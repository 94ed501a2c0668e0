"""What drives each feedback's effect in the findings check (``check_findings.py``): per scene and per goal, the
statistics a feedback's worth depends on, beside the gains, and the same statistics for the paper's setting.

- **same-class distractors** of a goal: the scene's other objects of the goal's class (its ``same_goal`` group
  excluded). A description tells the goal from them; without one, a detector's first sighting of the class is the
  goal only one time in (distractors + 1) when all are in view;
- **landmark / goal visibility**: the floor (m², navigable cells 0.5 m apart) from which an object's mass-centre
  column is in line of sight within the detector's range (``eval.detect_max_range_m``), the landmark's over the
  goal's (mean over the goal's landmarks): a landmark helps an exploring method when it can be seen from more of
  the home than the goal (the paper: "the provided nearby objects could be easier to find than the goal objects");
  beside it the footprint ratio, the one measure the paper's goal files give too;
- **landmark repeats**: the home's other objects of a landmark's class (mean over the goal's landmarks). "Next to
  the bed" takes an exploring method to a bed, and where the home has three, to the wrong one two times in three
  unless the landmark's attributes tell them apart;
- **rooms** and **navigable area**: how far an exploration has to go;
- **goal types** (big, small, ambiguous: :func:`pipeline.goals.build.group_type`): each type's SR without interaction
  and with yes/no, and the whole table with the goals weighted to the paper's mix of types (:func:`paper_mix_weights`:
  every type's goals share that type's share of the paper's 117, direct standardisation). A home of ten rooms repeats
  classes, so its goals are more often ambiguous than the paper's third, and an ambiguous goal is where a method
  without a description asks at the wrong instance; the weighted table says how much of the set's distance from
  the paper is its mix of goals rather than the methods (a what-if beside the check, not the check).

The paper's setting (:data:`PAPER_SETTING`) comes from navchat's goal files (``orion/user_simulator/goals``: 10
HM3D scenes, 117 goals: 39 big, 41 small, 37 ambiguous; :func:`navchat_statistics` computes it from them, and a
test checks the constants against the files when ``ZIPON_NAVCHAT_GOALS`` names them); HM3D's navigable area is its
paper's mean. The files list each scene's annotated objects, not every object, so the paper's distractor and
landmark-repeat counts are lower bounds.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np

#: the grid the visibility statistic samples the navigable floor on, metres
SAMPLE_M = 0.5
#: the landmark split: goals whose landmarks' classes have more other instances in the home than this (mean over the
#: goal's landmarks), and the others (the paper's goal files: 1.25)
LANDMARK_REPEATS = 2
#: the paper's setting, from navchat's goal files (:func:`navchat_statistics`) and HM3D's mean navigable floor
PAPER_SETTING = {"goals": 117, "types": {"ambiguous": 37, "big": 39, "small": 41}, "distractors per goal": 0.6,
                 "goals with distractors": 0.31, "landmark / goal footprint": 1.69, "landmark repeats": 1.25,
                 "goals with landmarks": 0.89, "rooms per scene": 4.0, "navigable m2": 112.5}


def navchat_statistics(folder: Path) -> dict:
    """:data:`PAPER_SETTING`'s goal statistics from navchat's goal files (one folder per scene, ``final.json`` and
    ``objects.json``). Footprints are navchat's ``mass`` (contour area in its map cells); "rooms per scene" counts
    the rooms navchat's goals are in (``room_id``), all the files say of a scene's rooms."""
    types: Counter = Counter()
    distractors, ratios, repeats, rooms, with_landmarks = [], [], [], [], 0
    scenes = sorted(p for p in Path(folder).iterdir() if (p / "final.json").is_file())
    if not scenes:
        raise FileNotFoundError(f"{folder}: no scene folder with a final.json (navchat's orion/user_simulator/goals)")
    for scene in scenes:
        final = json.loads((scene / "final.json").read_text())
        objects = json.loads((scene / "objects.json").read_text())
        goals = {k: v for k, v in final.items() if k != "room_info"}
        classes = Counter(v["name"] for v in objects.values())
        rooms.append(len({g["room_id"] for g in goals.values()}))
        for key, g in goals.items():
            types[g["type"]] += 1
            group = {key, *(x for x in (g.get("same_goal") or "").split("|") if x)}
            cls = objects[key]["name"] if key in objects else key.rsplit("_", 1)[0]
            distractors.append(classes[cls] - sum(objects.get(k, {}).get("name") == cls for k in group))
            marks = [m for m in (g.get("nearby_obj") or "").split("|") if m in objects]
            if marks:
                with_landmarks += 1
                repeats.append(float(np.mean([classes[objects[m]["name"]] - 1 for m in marks])))
                mass = json.loads(g["base"])["mass"] if isinstance(g.get("base"), str) else objects[key]["mass"]
                ratios.append(float(np.mean([objects[m]["mass"] for m in marks])) / max(float(mass), 1e-9))
    n = sum(types.values())
    return {"goals": n, "types": dict(sorted(types.items())), "distractors per goal": round(float(np.mean(distractors)), 2),
            "goals with distractors": round(float(np.mean(np.asarray(distractors) > 0)), 2),
            "landmark / goal footprint": round(float(np.median(ratios)), 2),
            "landmark repeats": round(float(np.mean(repeats)), 2), "goals with landmarks": round(with_landmarks / n, 2),
            "rooms per scene": round(float(np.mean(rooms)), 1)}


def seen_from_m2(sight, goals, index: np.ndarray, keys: tuple[str, ...], samples: np.ndarray, cell_m2: float,
                 reach_m: float) -> float:
    """Floor (m²) among ``samples`` ((N,2) navigable points) from which the mass-centre column of one of the objects
    ``keys`` is in line of sight (``sight``: the routes module's mesh test) within ``reach_m``; ``index`` is the
    goals' object index grid."""
    from pipeline.nav.region import own_cells, sight_levels

    order = goals.object_keys
    own = own_cells(np.isin(index, [order.index(k) + 1 for k in keys]))
    seen = np.zeros(len(samples), bool)
    for k in keys:
        o = goals.objects[k]
        mc = np.asarray(o.mass_center, np.float64)
        near = np.flatnonzero(np.hypot(*(samples - mc).T) <= reach_m)
        if len(near):
            seen[near] |= sight(samples[near], mc, sight_levels(o.z_range), own)
    return float(seen.sum()) * cell_m2


def scene_statistics(ws, params, stages) -> dict:
    """``{"scenes": {scene: {...}}, "goals": {"scene/goal": {...}}}``: the statistics of the module docstring."""
    from pipeline.nav.region import MeshSight
    from pipeline.scene import Scene

    out: dict = {"scenes": {}, "goals": {}}
    reach = params.eval.detect_max_range_m
    for name in params.scenes:
        scene = Scene(ws, params, name, stages)
        grid, goals = scene.grid, scene.goals
        sight = MeshSight.from_mesh(scene.recon.mesh_path, floor_z=scene.recon.floor_z,
                                    camera_height_m=scene.camera_height_m, grid=grid)
        step = max(1, int(round(SAMPLE_M / grid.cell_size_m)))
        rr, cc = np.nonzero(scene.navigable[::step, ::step])
        samples = grid.cell_to_world(np.stack([rr * step, cc * step], axis=1)).astype(np.float64)
        cell_m2 = (step * grid.cell_size_m) ** 2
        classes = Counter(o.cls for o in goals.objects.values())
        index = goals.object_index()
        seen: dict[tuple[str, ...], float] = {}

        def seen_of(keys: tuple[str, ...]) -> float:
            if keys not in seen:
                seen[keys] = seen_from_m2(sight, goals, index, keys, samples, cell_m2, reach)
            return seen[keys]

        rows = []
        for g in goals.goals:
            cls = goals.objects[g.object_keys[0]].cls
            marks = [lm["object"] for lm in g.landmarks if lm.get("object") in goals.objects]
            goal_seen = seen_of(tuple(g.object_keys))
            row = {"type": g.type, "distractors": classes[cls] - sum(goals.objects[k].cls == cls for k in g.object_keys),
                   "goal seen m2": round(goal_seen, 2)}
            if marks:
                lm_seen = float(np.mean([seen_of((k,)) for k in marks]))
                footprint = float(np.mean([goals.objects[k].area_m2 for k in marks]))
                repeats = float(np.mean([classes[goals.objects[k].cls] - 1 for k in marks]))
                row.update({"landmark seen m2": round(lm_seen, 2), "landmark repeats": round(repeats, 2),
                            "landmark / goal seen": round(lm_seen / max(goal_seen, cell_m2), 2),
                            "landmark / goal footprint": round(footprint / max(goals.objects[g.object_keys[0]].area_m2,
                                                                               1e-6), 2)})
            out["goals"][f"{name}/{g.id}"] = row
            rows.append(row)
        ratios = [r["landmark / goal seen"] for r in rows if "landmark / goal seen" in r]
        feet = [r["landmark / goal footprint"] for r in rows if "landmark / goal footprint" in r]
        out["scenes"][name] = {
            "rooms": len(scene.room_of_cell[1]), "navigable m2": round(float(scene.navigable.sum()) * grid.cell_size_m ** 2, 1),
            "goals": len(rows), "distractors per goal": round(float(np.mean([r["distractors"] for r in rows])), 2),
            "goals with distractors": round(float(np.mean([r["distractors"] > 0 for r in rows])), 2),
            "landmark / goal seen": round(float(np.median(ratios)), 2) if ratios else None,
            "landmark / goal footprint": round(float(np.median(feet)), 2) if feet else None,
            "landmark repeats": round(float(np.mean([r["landmark repeats"] for r in rows if "landmark repeats" in r])), 2)
            if ratios else None,
            "goals with landmarks": round(len(ratios) / max(len(rows), 1), 2)}
    return out


def gains(tables: dict, methods: tuple[str, ...], settings: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """``{kind: {method: SR gain over yes/no}}`` and ``"mixed - best single"`` from one set of Cells tables."""
    sr = tables["SR"]
    col = {s: sr[:, settings.index(s)] for s in settings}
    kinds = [s for s in settings if s not in ("none", "yesno", "mixed")]
    out = {k: {m: float(col[k][i] - col["yesno"][i]) for i, m in enumerate(methods)} for k in kinds}
    out["mixed - best single"] = {m: float(col["mixed"][i] - max(col[k][i] for k in kinds)) for i, m in enumerate(methods)}
    return out


def split_gain(cells_of, episodes: list[dict], goals: set, kind: str) -> dict[str, float] | None:
    """SR gain of ``kind`` over yes/no of each method on the episodes of ``goals`` ("scene/goal"); None without any."""
    chosen = [e for e in episodes if f"{e['scene']}/{e['goal']}" in goals]
    if not chosen:
        return None
    c = cells_of(chosen)
    return gains(c.tables(), c.methods, c.settings)[kind]


def driver_figures(episodes: list[dict], stats: dict, cells_of) -> dict:
    """Per scene its statistics and SR gains; per goal group (with / without same-class distractors; landmark seen from
    more / less floor than the goal; landmark classes repeated more / less) the descriptive, landmark and mixed gains.
    ``cells_of(episodes)`` makes the check's Cells (with ``methods`` and ``settings``)."""
    scenes = {}
    for name, st in stats["scenes"].items():
        chosen = [e for e in episodes if e["scene"] == name]
        if chosen:
            c = cells_of(chosen)
            scenes[name] = {**st, "gains": gains(c.tables(), c.methods, c.settings)}
    goal_stats = stats["goals"]
    crowded = {g for g, r in goal_stats.items() if r["distractors"] > 0}
    visible = {g for g, r in goal_stats.items() if r.get("landmark / goal seen", 0) > 1}
    hidden = {g for g, r in goal_stats.items() if "landmark / goal seen" in r and r["landmark / goal seen"] <= 1}
    crowded_marks = {g for g, r in goal_stats.items() if r.get("landmark repeats", 0) > LANDMARK_REPEATS}
    few_marks = {g for g, r in goal_stats.items() if "landmark repeats" in r and r["landmark repeats"] <= LANDMARK_REPEATS}
    groups = {
        "descriptive, goals with same-class distractors": (crowded, "descriptive"),
        "descriptive, goals without": (set(goal_stats) - crowded, "descriptive"),
        "landmark, landmark seen from more floor than the goal": (visible, "landmark"),
        "landmark, landmark seen from as much floor or less": (hidden, "landmark"),
        f"landmark, its landmarks' classes with more than {LANDMARK_REPEATS} other instances": (crowded_marks, "landmark"),
        f"landmark, its landmarks' classes with {LANDMARK_REPEATS} or fewer": (few_marks, "landmark"),
        # with a route, the landmark says which of the candidates near the route's end is meant: where its class
        # repeats, a map's or a sighting's instance of it is more often another one
        f"mixed - best single, its landmarks' classes with more than {LANDMARK_REPEATS} other instances":
            (crowded_marks, "mixed - best single"),
        f"mixed - best single, its landmarks' classes with {LANDMARK_REPEATS} or fewer": (few_marks, "mixed - best single"),
    }
    split = {text: {"goals": len(goals), "gains": split_gain(cells_of, episodes, goals, kind)}
             for text, (goals, kind) in groups.items()}
    types = {g: r["type"] for g, r in goal_stats.items()}
    return {"scenes": scenes, "groups": split, "types": type_figures(episodes, types, cells_of),
            "paper setting": PAPER_SETTING}


def paper_mix_weights(goals: list[tuple[str, str]], types: dict[str, str]) -> np.ndarray:
    """Per goal of ``goals`` ((scene, goal) pairs; ``types`` "scene/goal" -> its type) the weight that gives each type
    the share it has among the paper's goals (:data:`PAPER_SETTING`), split evenly over the type's goals; the shares of
    types the set lacks go to the others in proportion. The weights sum to the number of goals."""
    missing = [f"{s}/{g}" for s, g in goals if f"{s}/{g}" not in types]
    if missing:
        raise ValueError(f"{len(missing)} goal(s) of the episodes are not among the workspace's goals (first: "
                         f"{', '.join(missing[:3])}): the results come from other goals than the workspace holds now")
    kinds = [types[f"{s}/{g}"] for s, g in goals]
    count = Counter(kinds)
    paper = PAPER_SETTING["types"]
    share = {t: paper.get(t, 0) for t in count}
    if not sum(share.values()):
        raise ValueError(f"no goal of the paper's types {sorted(paper)} among the set's {sorted(count)}")
    total = sum(share.values())
    return np.array([share[k] / total / count[k] for k in kinds]) * len(goals)


def type_figures(episodes: list[dict], types: dict[str, str], cells_of) -> dict:
    """Per goal type its goals and each method's SR without interaction and with yes/no (``types``: "scene/goal" ->
    its type; ``cells_of`` as in :func:`driver_figures`)."""
    out = {}
    for t in sorted(set(types.values())):
        chosen = [e for e in episodes if types.get(f"{e['scene']}/{e['goal']}") == t]
        if not chosen:
            continue
        c = cells_of(chosen)
        sr = c.tables()["SR"]
        out[t] = {"goals": len(c.goals), "paper goals": PAPER_SETTING["types"].get(t, 0),
                  **{f"SR {s}": {m: float(sr[i, c.settings.index(s)]) for i, m in enumerate(c.methods)}
                     for s in ("none", "yesno")}}
    return out


def print_drivers(doc: dict, names: dict[str, str]) -> None:
    """The driver tables of :func:`driver_figures` (``names``: method -> its label)."""
    methods = list(names)
    print("\nWhat drives each effect, per scene (SR gain over yes/no, points)")
    print(f"{'scene':16}{'rooms':>6}{'nav m2':>8}{'goals':>6}{'distr/goal':>11}{'w/ distr':>9}{'lm/goal seen':>13}"
          f"{'lm/goal footprint':>18}{'lm repeats':>11}")
    for name, s in doc["scenes"].items():
        g = s["gains"]
        seen = "-" if s["landmark / goal seen"] is None else f"{s['landmark / goal seen']:.2f}"
        per = lambda k: " ".join(f"{names[m]} {g[k][m]:+5.1f}" for m in methods)  # noqa: E731
        foot = "-" if s["landmark / goal footprint"] is None else f"{s['landmark / goal footprint']:.2f}"
        repeats = "-" if s.get("landmark repeats") is None else f"{s['landmark repeats']:.2f}"
        print(f"{name:16}{s['rooms']:>6}{s['navigable m2']:>8.1f}{s['goals']:>6}{s['distractors per goal']:>11.2f}"
              f"{s['goals with distractors']:>9.2f}{seen:>13}{foot:>18}{repeats:>11}")
        for k in ("descriptive", "landmark", "procedural", "mixed - best single"):
            print(f"{'':18}{k:20} {per(k)}")
    print("\nBy goal (SR gain over yes/no, points; mixed: over the method's best single kind)")
    for text, v in doc["groups"].items():
        g = v["gains"]
        per = "no episodes" if g is None else ", ".join(f"{names[m]} {g[m]:+.1f}" for m in methods)
        print(f"  {text} ({v['goals']} goals): {per}")
    print("\nBy goal type (goals: this set / the paper's; SR %)")
    for t, v in doc["types"].items():
        for s in ("none", "yesno"):
            per = " ".join(f"{names[m]} {v[f'SR {s}'][m]:5.1f}" for m in methods)
            head = f"  {t:10}{v['goals']:>4} / {v['paper goals']:<4}" if s == "none" else " " * 23
            print(f"{head} {s:6} {per}")
    p = doc["paper setting"]
    print(f"\nthe paper's setting (navchat's goal files; HM3D): {p['goals']} goals ({', '.join(f'{v} {k}' for k, v in p['types'].items())}), "
          f"distractors per goal {p['distractors per goal']} (goals with any {p['goals with distractors']}), "
          f"landmark / goal footprint (median) {p['landmark / goal footprint']}, other instances of a landmark's class "
          f"{p['landmark repeats']}, goals with landmarks "
          f"{p['goals with landmarks']}, rooms with goals per scene {p['rooms per scene']}, navigable m2 {p['navigable m2']}")
