"""Metrics on hand-made episodes match hand computation."""

import numpy as np
import pytest
from scipy.stats import wilcoxon

from orion_eval.episode import spl, sit
from orion_eval.metrics import success_by_turn, summarize, wilcoxon_tests


def _ep(method, seed, goal, success, l, a, turns, fb="yesno"):
    s = 1.0 if success else 0.0
    return {"scene": "s", "method": method, "feedback": fb, "seed": seed, "goal": goal, "goal_type": "big",
            "success": success, "spl": spl(s, l, a), "sit": sit(s, turns), "talk_turns": turns}


def test_spl_and_sit_formulas():
    assert spl(1.0, 4.0, 8.0) == 0.5  # S * l / max(a, l)
    assert spl(1.0, 4.0, 2.0) == 1.0  # shorter than the reference counts as l
    assert spl(0.0, 4.0, 4.0) == 0.0
    assert sit(1.0, 3) == pytest.approx(1 / 3) and sit(1.0, 0) == 1.0 and sit(0.0, 2) == 0.0


def test_tables_are_means_over_seeds_of_episode_means():
    eps = [_ep("a", 0, "g1", True, 4, 8, 1), _ep("a", 0, "g2", False, 3, 3, 5),
           _ep("a", 1, "g1", True, 4, 4, 2), _ep("a", 1, "g2", True, 2, 4, 4)]
    res = summarize(eps, methods=["a"], feedback=["yesno"], seeds=[0, 1], scenes=["s"])
    cell = res["overall"]["a"]["yesno"]
    # seed 0: SR 50, SPL (0.5 + 0)/2 = 25, SIT (1 + 0)/2 = 50; seed 1: SR 100, SPL (1 + 0.5)/2 = 75, SIT (1/2 + 1/4)/2
    assert cell["SR"] == pytest.approx(75.0) and cell["SR_std"] == pytest.approx(25.0)
    assert cell["SPL"] == pytest.approx(50.0)
    assert cell["SIT"] == pytest.approx((50.0 + 37.5) / 2)
    assert cell["episodes"] == 4
    assert res["by_goal"]["s"]["g2"]["a"]["yesno"]["SR"] == pytest.approx(50.0)


def test_success_by_turn_is_cumulative():
    eps = [_ep("a", 0, "g1", True, 1, 1, 1), _ep("a", 0, "g2", True, 1, 1, 3), _ep("a", 0, "g3", False, 1, 1, 5)]
    curve = success_by_turn(eps, 5)["a"]["yesno"]
    assert curve == pytest.approx([100 / 3, 100 / 3, 200 / 3, 200 / 3, 200 / 3], abs=1e-3)


def test_wilcoxon_matches_scipy_on_paired_episodes():
    rng = np.random.default_rng(0)
    xa = rng.random(30) < 0.8
    xb = rng.random(30) < 0.4
    eps = [_ep("a", 0, f"g{i}", bool(v), 1, 1, 1) for i, v in enumerate(xa)]
    eps += [_ep("b", 0, f"g{i}", bool(v), 1, 1, 1) for i, v in enumerate(xb)]
    (t,) = wilcoxon_tests(eps, "SR")
    ref = wilcoxon(xa.astype(float), xb.astype(float))
    assert t["pairs"] == 30 and t["p"] == pytest.approx(ref.pvalue) and t["statistic"] == pytest.approx(ref.statistic)
    same = [dict(e, method="c") for e in eps if e["method"] == "a"]
    assert [x for x in wilcoxon_tests(eps + same, "SR") if {x["a"], x["b"]} == {"a", "c"}][0]["p"] is None


def test_per_setting_wilcoxon_and_the_significance_star():
    from orion_eval.metrics import significantly_best, wilcoxon_by_feedback

    rng = np.random.default_rng(1)
    eps = []
    for fb, (pa, pb) in {"yesno": (0.9, 0.2), "none": (0.5, 0.5)}.items():
        xa, xb = rng.random(40) < pa, rng.random(40) < pb
        eps += [_ep("a", 0, f"g{i}", bool(v), 1, 1, 1, fb) for i, v in enumerate(xa)]
        eps += [_ep("b", 0, f"g{i}", bool(v), 1, 1, 1, fb) for i, v in enumerate(xb)]
    tests = wilcoxon_by_feedback(eps, "SR")
    assert {t["feedback"] for t in tests} == {"yesno", "none"} and all(t["pairs"] == 40 for t in tests)
    yes = [t for t in tests if t["feedback"] == "yesno"][0]
    assert yes["p"] == pytest.approx(wilcoxon(*[np.array([float(e["success"]) for e in eps if e["method"] == m
                                                          and e["feedback"] == "yesno"]) for m in "ab"]).pvalue)
    assert yes["p"] < 0.001 and significantly_best(tests, "a") == {"yesno"} and significantly_best(tests, "b") == set()


def test_a_buildings_episodes_are_also_reported_by_whether_they_cross_floors():
    eps = [{**_ep("a", 0, "g1", True, 4, 8, 1), "cross_floor": False}, {**_ep("a", 0, "g1", False, 9, 3, 5),
                                                                         "cross_floor": True},
           {**_ep("a", 1, "g1", True, 9, 9, 2), "cross_floor": True}]
    res = summarize(eps, methods=["a"], feedback=["yesno"], seeds=[0, 1], scenes=["s"])
    floors = res["by_floors"]["a"]
    assert floors["same floor"]["yesno"]["episodes"] == 1 and floors["same floor"]["yesno"]["SR"] == 100.0
    assert floors["cross floor"]["yesno"]["episodes"] == 2 and floors["cross floor"]["yesno"]["SR"] == 50.0
    flat = summarize([_ep("a", 0, "g1", True, 4, 8, 1)], methods=["a"], feedback=["yesno"], seeds=[0], scenes=["s"])
    assert "by_floors" not in flat  # single-floor results as before buildings
