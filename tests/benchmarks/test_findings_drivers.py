"""benchmarks/findings_drivers.py: what drives each feedback's effect — the paper's setting from navchat's goal files,
and the per-goal splits of the gains — on files and episodes whose answers are known."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture
def drivers(load_script):
    return load_script("findings_drivers")


def navchat_scene(folder: Path, objects: dict, goals: dict) -> None:
    """One navchat goal folder: ``objects`` {key: (class, mass)}, ``goals`` {key: final.json entry}."""
    folder.mkdir(parents=True)
    (folder / "objects.json").write_text(json.dumps(
        {k: {"name": c, "center": [0, 0], "mass": m, "contour": []} for k, (c, m) in objects.items()}))
    (folder / "final.json").write_text(json.dumps({"room_info": {"bedroom": "Alice"}, **goals}))


def goal(kind: str, room: str, mass: float, nearby: str = "", same: str | None = None) -> dict:
    g = {"base": json.dumps({"center": [0, 0], "mass": mass}), "nearby_obj": nearby, "object_desc": "", "attr": None,
         "room_id": room, "explain": "", "type": kind}
    if same:
        g["same_goal"] = same
    return g


def test_the_paper_setting_statistics_from_navchat_files(drivers, tmp_path):
    navchat_scene(tmp_path / "a", {"chair_0": ("chair", 10), "chair_1": ("chair", 10), "chair_2": ("chair", 10),
                                   "bed_0": ("bed", 40), "lamp_0": ("lamp", 2)},
                  {"chair_0": goal("ambiguous", "bedroom_1", 10, "bed_0", same="chair_1"),
                   "lamp_0": goal("small", "bedroom_1", 2, "bed_0|chair_2"), "bed_0": goal("big", "living_1", 40)})
    navchat_scene(tmp_path / "b", {"sofa_0": ("sofa", 30)}, {"sofa_0": goal("big", "living_1", 30, "tv_0")})
    s = drivers.navchat_statistics(tmp_path)
    assert s["goals"] == 4 and s["types"] == {"ambiguous": 1, "big": 2, "small": 1}
    # chair_0's group is chair_0 and chair_1: chair_2 is its one distractor; nobody else has one
    assert s["distractors per goal"] == 0.25 and s["goals with distractors"] == 0.25
    # landmarks listed in objects.json: chair_0 -> bed (40/10), lamp_0 -> bed and chair (25/2); tv_0 is not listed
    assert s["landmark / goal footprint"] == pytest.approx((4.0 + 12.5) / 2)
    # other listed objects of a landmark's class: the bed has none, chair_2 two other chairs (lamp_0: (0 + 2) / 2)
    assert s["landmark repeats"] == pytest.approx((0.0 + 1.0) / 2)
    assert s["goals with landmarks"] == 0.5 and s["rooms per scene"] == 1.5


def test_a_folder_without_navchat_scenes_is_refused(drivers, tmp_path):
    with pytest.raises(FileNotFoundError, match="no scene folder with a final.json"):
        drivers.navchat_statistics(tmp_path)


NAVCHAT = os.environ.get("ZIPON_NAVCHAT_GOALS")  # navchat's orion/user_simulator/goals (never committed)


@pytest.mark.skipif(not NAVCHAT, reason="set ZIPON_NAVCHAT_GOALS to navchat's orion/user_simulator/goals folder")
def test_the_paper_setting_constants_are_navchats(drivers):
    s = drivers.navchat_statistics(Path(NAVCHAT))
    assert s == {k: v for k, v in drivers.PAPER_SETTING.items() if k != "navigable m2"}
    assert s["types"] == {"ambiguous": 37, "big": 39, "small": 41}  # the paper's 117 goals


def episodes(outcomes: dict) -> list[dict]:
    """``outcomes`` {(goal, method, setting): successes of 4 seeds}: one scene "s"."""
    out = []
    for (g, m, f), wins in outcomes.items():
        out += [{"scene": "s", "goal": g, "method": m, "feedback": f, "seed": k, "success": k < wins, "spl": 0.0,
                 "sit": 0.0} for k in range(4)]
    return out


def test_gains_are_split_by_what_drives_them(drivers, load_script):
    check = load_script("check_findings")
    settings = check.SETTINGS
    outcomes = {}
    for g, crowded in (("g1", True), ("g2", False)):
        for m in check.METHODS:
            for f in settings:
                # a description helps only where there are distractors; landmarks only where the landmark shows more;
                # mixed matches the best single kind where the landmark repeats, and falls under it where it does not
                wins = 1 + (3 if (f == "descriptive" and crowded) or (f == "landmark" and not crowded) else 0)
                wins = (4 if crowded else 2) if f == "mixed" else wins
                outcomes[(g, m, f)] = wins
    stats = {"scenes": {"s": {"rooms": 3, "navigable m2": 50.0, "goals": 2, "distractors per goal": 0.5,
                              "goals with distractors": 0.5, "landmark / goal seen": 1.0,
                              "landmark / goal footprint": 2.0, "goals with landmarks": 1.0}},
             "goals": {"s/g1": {"type": "ambiguous", "distractors": 2, "landmark / goal seen": 0.5,
                                "landmark repeats": 2.5},
                       "s/g2": {"type": "big", "distractors": 0, "landmark / goal seen": 3.0, "landmark repeats": 0.0}}}
    doc = drivers.driver_figures(episodes(outcomes), stats, check.Cells)
    groups = doc["groups"]
    assert groups["descriptive, goals with same-class distractors"] == {
        "goals": 1, "gains": {m: 75.0 for m in check.METHODS}}
    assert groups["descriptive, goals without"]["gains"] == {m: 0.0 for m in check.METHODS}
    assert groups["landmark, landmark seen from more floor than the goal"]["gains"] == {m: 75.0 for m in check.METHODS}
    assert groups["landmark, landmark seen from as much floor or less"]["gains"] == {m: 0.0 for m in check.METHODS}
    # g1's landmark class has 2.5 other instances (more than 2), g2's none: the landmark gain is g2's
    assert groups["landmark, its landmarks' classes with more than 2 other instances"] == {
        "goals": 1, "gains": {m: 0.0 for m in check.METHODS}}
    assert groups["landmark, its landmarks' classes with 2 or fewer"]["gains"] == {m: 75.0 for m in check.METHODS}
    assert groups["mixed - best single, its landmarks' classes with more than 2 other instances"] == {
        "goals": 1, "gains": {m: 0.0 for m in check.METHODS}}
    assert groups["mixed - best single, its landmarks' classes with 2 or fewer"]["gains"] == {
        m: -50.0 for m in check.METHODS}
    scene = doc["scenes"]["s"]["gains"]
    assert scene["descriptive"] == {m: 37.5 for m in check.METHODS} and scene["procedural"]["cow"] == 0.0
    assert doc["paper setting"]["goals"] == 117
    # one success in 4 seeds in none and yes/no for both goals: 25 % per type, and the paper's counts beside
    assert doc["types"]["ambiguous"] == {"goals": 1, "paper goals": 37, "SR none": {m: 25.0 for m in check.METHODS},
                                         "SR yesno": {m: 25.0 for m in check.METHODS}}
    assert doc["types"]["big"]["goals"] == 1 and doc["types"]["big"]["paper goals"] == 39


def test_paper_mix_weights_give_each_type_its_share_of_the_papers_goals(drivers):
    goals = [("s", "a1"), ("s", "a2"), ("s", "a3"), ("s", "b1"), ("t", "s1")]
    types = {"s/a1": "ambiguous", "s/a2": "ambiguous", "s/a3": "ambiguous", "s/b1": "big", "t/s1": "small"}
    w = drivers.paper_mix_weights(goals, types)
    # shares 37 / 39 / 41 of 117, each split over its type's goals; the weights sum to the goal count
    assert w == pytest.approx(np.array([37 / 3, 37 / 3, 37 / 3, 39, 41]) / 117 * 5)
    # a set without small goals: ambiguous and big share the whole weight in the paper's 37 : 39
    w = drivers.paper_mix_weights(goals[:4], types)
    assert w == pytest.approx(np.array([37 / 3, 37 / 3, 37 / 3, 39]) / 76 * 4)


def test_paper_mix_weights_refuse_a_set_without_the_papers_types(drivers):
    with pytest.raises(ValueError, match=r"no goal of the paper's types \['ambiguous', 'big', 'small'\] among the "
                                         r"set's \['custom'\]"):
        drivers.paper_mix_weights([("s", "g")], {"s/g": "custom"})


def test_paper_mix_weights_refuse_goals_the_workspace_does_not_hold(drivers):
    with pytest.raises(ValueError, match=r"1 goal\(s\) of the episodes are not among the workspace's goals \(first: "
                                         r"t/gone\): the results come from other goals"):
        drivers.paper_mix_weights([("s", "g"), ("t", "gone")], {"s/g": "big"})
