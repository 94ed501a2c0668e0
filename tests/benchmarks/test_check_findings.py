"""benchmarks/check_findings.py's ablation report (ORION with one module taken away, against the paper's Table II):
rows, SR drops with their bootstrap intervals, and the paper's reading of them, on episodes whose outcomes are known.

The check itself builds scenes and evaluates them (minutes; docs/evaluation-modules.md); these tests need neither.
"""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture
def check(load_script):
    return load_script("check_findings")


def episodes(rates: dict[str, float], goals: int = 20, seeds: int = 5) -> list[dict]:
    """Mixed-setting episodes: method m succeeds in round(rate * seeds) of each goal's seeds (SPL 0.5, SIT 0.25)."""
    out = []
    for m, rate in rates.items():
        for g in range(goals):
            for s in range(seeds):
                ok = s < round(rate * seeds)
                out.append({"method": m, "feedback": "mixed", "scene": "a", "goal": f"g{g}", "seed": s,
                            "success": ok, "spl": 0.5 * ok, "sit": 0.25 * ok})
    return out


def test_ablation_rows_drops_and_findings(check):
    eps = episodes({"orion": 0.8, "orion_wo_mem": 0.8 - 0.2, "orion_wo_exp": 0.4, "orion_wo_det": 0.6,
                    "orion_wo_map": 0.2})
    eps += [dict(e, feedback="yesno", success=False) for e in eps[:50]]  # other settings are not read
    a = check.ablation_figures(eps, draws=200)
    assert a["rows"]["orion"] == pytest.approx((80.0, 40.0, 20.0))
    assert a["rows"]["orion_wo_map"] == pytest.approx((20.0, 10.0, 5.0))
    assert a["drops"] == pytest.approx({"orion_wo_mem": 20.0, "orion_wo_exp": 40.0, "orion_wo_det": 20.0,
                                        "orion_wo_map": 60.0})
    # every goal has the same outcomes: every bootstrap draw gives the same drop
    assert a["intervals"]["orion_wo_map"] == pytest.approx((60.0, 60.0))
    holds = {text[:4]: ok for text, ok, _ in a["findings"]}
    assert holds == {"(A1)": True, "(A2)": True, "(A3)": False}  # w/o mem ties w/o det: not the least


def test_an_ablation_better_than_orion_fails_the_first_reading(check):
    a = check.ablation_figures(episodes({"orion": 0.6, "orion_wo_mem": 0.8}), draws=50)
    assert a["drops"] == pytest.approx({"orion_wo_mem": -20.0})
    text, holds, detail = a["findings"][0]
    assert text.startswith("(A1)") and not holds and "w/o mem -20.0" in detail


def test_the_report_needs_orion_and_an_ablation(check):
    with pytest.raises(ValueError, match="ORION's and at least one ablation's mixed episodes"):
        check.ablation_figures(episodes({"orion": 0.5}), draws=10)
    with pytest.raises(ValueError, match="ORION's and at least one ablation's mixed episodes"):
        check.ablation_figures(episodes({"orion_wo_map": 0.5}), draws=10)


def run_check(*args: str):
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[2] / "benchmarks" / "check_findings.py"
    return subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(("stale", "line"), [
    ({"a/goals": "code changed: pipeline/goals/feedback/landmark.py"},
     "evaluated on stale artifacts (run.stale; rerun them with zipon run): a/goals (code changed: "
     "pipeline/goals/feedback/landmark.py)"),
    (None, "artifacts evaluated: not recorded (a results.json from before run.artifacts / run.stale)"),
    ({}, None),
])
def test_the_report_says_when_the_episodes_came_from_stale_artifacts(check, capsys, stale, line):
    # SR varying over the cells (a constant table has no rank correlation)
    eps = [dict(e, feedback=f) for j, f in enumerate(check.SETTINGS)
           for e in episodes({m: ((i + j) % 5) / 4 for i, m in enumerate(check.METHODS)}, goals=4, seeds=4)]
    run = {"scenes": ["a"], "seeds": [0, 1], "encoders": {"a": {"vlmap": {"kind": "simulated"}}},
           "detection": {"a": "simulated detectors"}}
    if stale is not None:
        run["stale"] = stale
    check.print_report({"run": run, "episodes": eps}, check.Cells(eps), 10)
    text = capsys.readouterr().out
    if line is None:
        assert "stale" not in text and "not recorded" not in text
    else:
        assert line in text.splitlines()


def test_a_results_file_that_cannot_be_read_is_refused_with_its_name(tmp_path):
    missing = tmp_path / "nowhere.json"
    out = run_check("--results", str(missing))
    assert out.returncode == 2 and f"--results {missing}: cannot be read" in out.stderr and "Traceback" not in out.stderr
    broken = tmp_path / "broken.json"
    broken.write_text('{"run": {}}')
    out = run_check("--results", str(broken))
    assert out.returncode == 2 and "KeyError" in out.stderr and "with 'episodes'" in out.stderr


def test_ablations_asked_of_results_without_them_are_refused(tmp_path):
    import json

    path = tmp_path / "results.json"
    path.write_text(json.dumps({"episodes": episodes({"orion": 0.5})}))
    out = run_check("--results", str(path), "--ablations", "--boot", "10")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"--ablations: {path} holds no mixed episodes of ORION and of one of its ablations" in out.stderr
    assert "found mixed episodes of ['orion']" in out.stderr and out.stdout == ""


def test_the_checks_apartments_have_the_rooms_asked_for(check, tmp_path):
    """``--rooms`` reaches the simulator: every findings apartment of the check's params has that many rooms (the
    default sizes them like an HM3D scene; the report prints each one's measured navigable floor)."""
    from benchmarks.bench_eval import build_params

    from pipeline.paramsfile import load_params
    from pipeline.sim.scene import generate_floor

    (tmp_path / "params.yaml").write_text(build_params(3, 480, "findings", 2027, check.HM3D_ROOMS))
    params = load_params(tmp_path / "params.yaml")
    assert (params.simulate.rooms_min, params.simulate.rooms_max) == (10, 10)
    for name in params.scenes:
        _, plan = generate_floor(name, params.simulate)
        assert len(plan.rooms) == 10
    (tmp_path / "params.yaml").write_text(build_params(1, 240, "findings", 2027))
    default = load_params(tmp_path / "params.yaml").simulate
    assert (default.rooms_min, default.rooms_max) == (6, 7)  # the simulator's own range when not asked


@pytest.mark.parametrize(("option", "field", "expected"), [
    (["--rooms", "1"], "simulate.rooms_min", "greater than or equal to 2"),
    (["--max-steps", "0"], "eval.max_steps", "greater than 0"),
])
def test_bad_options_are_refused_before_anything_is_built(tmp_path, option, field, expected):
    """An option outside the params' bounds exits 2 with the field and the bound, and nothing is built or written."""
    ws = tmp_path / "ws"
    out = run_check("--workspace", str(ws), "--scenes", "1", *option)
    assert out.returncode == 2 and "Traceback" not in out.stderr and out.stdout == ""
    assert f"the check's params: {field}: Input should be {expected}" in out.stderr
    assert "(set by --scenes, --rooms, --frames, --prefix, --seed, --workers and --max-steps)" in out.stderr
    assert not ws.exists()


def test_a_prefix_that_cannot_name_a_scene_is_refused_before_anything_is_built(tmp_path):
    ws = tmp_path / "ws"
    out = run_check("--workspace", str(ws), "--scenes", "1", "--prefix", "9 homes")
    assert out.returncode == 2 and "Traceback" not in out.stderr and out.stdout == ""
    assert "--prefix '9 homes': a scene name's prefix must be letters, digits and underscores" in out.stderr
    assert not ws.exists()


def test_a_fresh_scene_set_is_named_by_its_prefix_and_seed(check, tmp_path):
    """``--prefix`` / ``--seed`` choose the scenes' names and ``simulate.seed``: another set of homes."""
    from benchmarks.bench_eval import build_params

    from pipeline.paramsfile import load_params

    (tmp_path / "params.yaml").write_text(build_params(2, 240, "fresh_df", 60217, None))
    params = load_params(tmp_path / "params.yaml")
    assert list(params.scenes) == ["fresh_df_00", "fresh_df_01"] and params.simulate.seed == 60217
    assert (check.PREFIX, check.SEED) == ("findings", 2027)  # the check's own set when none is named


def test_a_results_report_finds_the_workspace_of_its_scenes(check, tmp_path):
    """``--results`` with ``--workspace``: the drivers are computed on the workspace's params narrowed to the scenes the
    results hold; a workspace without them (or without params) gives None, and the report says it computed none."""
    from benchmarks.bench_eval import build_params

    assert check.workspace_of(tmp_path, ["fresh_df_00"]) is None  # no params.yaml
    (tmp_path / "params.yaml").write_text(build_params(3, 240, "fresh_df", 60217, None))
    ws, params = check.workspace_of(tmp_path, ["fresh_df_02", "fresh_df_00"])
    assert list(params.scenes) == ["fresh_df_00", "fresh_df_02"] and ws.params_path == tmp_path / "params.yaml"
    assert check.workspace_of(tmp_path, ["fresh_df_00", "other_00"]) is None


def test_the_drivers_report_weighs_the_goals_to_the_papers_mix_of_types(check, capsys):
    """Three goals, one per type, whose SR differ by type and method: the what-if table is the types' SR weighted
    37 : 39 : 41 (the paper's ambiguous, big and small goals), and its figures are the check's on that table."""
    import numpy as np
    from scipy.stats import spearmanr

    base, plus = {"ambiguous": 0, "big": 1, "small": 2}, {"cow": 0, "vlmap": 1, "cf": 1, "orion": 2}
    eps = [{"method": m, "feedback": f, "scene": "s", "goal": t, "seed": k, "success": k < base[t] + plus[m],
            "spl": 0.5 * (k < base[t] + plus[m]), "sit": 0.25 * (k < base[t] + plus[m])} for t in base for m in check.METHODS for f in check.SETTINGS for k in range(4)]
    stats = {"scenes": {"s": {"rooms": 3, "navigable m2": 50.0, "goals": 3, "distractors per goal": 1.0,
                              "goals with distractors": 0.33, "landmark / goal seen": None,
                              "landmark / goal footprint": None, "goals with landmarks": 0.0}},
             "goals": {f"s/{t}": {"type": t, "distractors": int(t == "ambiguous")} for t in base}}
    doc = check.drivers_report(eps, check.Cells(eps), stats)
    mean_base = (37 * 0 + 39 * 1 + 41 * 2) / 117
    table = np.array([[25.0 * (plus[m] + mean_base)] * len(check.SETTINGS) for m in check.METHODS])
    paper = check.paper_tables()["SR"]
    figures = doc["paper mix"]["figures"]
    assert figures["SR mean |d|"] == pytest.approx(float(np.mean(np.abs(table - paper))))
    assert figures["SR spearman"] == pytest.approx(float(spearmanr(table.ravel(), paper.ravel())[0]))
    assert doc["types"]["small"]["SR yesno"] == {"cow": 50.0, "vlmap": 75.0, "cf": 75.0, "orion": 100.0}
    out = capsys.readouterr().out
    assert "ambiguous    1 / 37   none   CoW   0.0 VLMap  25.0 CF  25.0 ORION  50.0" in out
    assert (f"weighted to the paper's mix of types (a what-if, not the check): SR Spearman rho "
            f"{figures['SR spearman']:.2f}, mean |d| {figures['SR mean |d|']:.1f}; findings (1) does not") in out


def test_the_json_records_the_scene_set_from_the_workspace_params(check, tmp_path):
    """A report from ``--results`` records the set as the check's own run does: prefix, simulate.seed, rooms, frames."""
    from benchmarks.bench_eval import build_params

    (tmp_path / "params.yaml").write_text(build_params(2, 240, "fresh_df", 60217, None))
    _, params = check.workspace_of(tmp_path, ["fresh_df_00", "fresh_df_01"])
    assert check.scene_set(params, 3) == {"prefix": "fresh_df", "seed": 60217, "rooms": [6, 7], "frames": 240,
                                          "scenes": ["fresh_df_00", "fresh_df_01"], "seeds": 3}
    (tmp_path / "params.yaml").write_text(build_params(1, 480, "fresh_hm", 91813, 10))
    _, params = check.workspace_of(tmp_path, ["fresh_hm_00"])
    assert check.scene_set(params, 5, {"fresh_hm_00": 101.5}) == {
        "prefix": "fresh_hm", "seed": 91813, "rooms": 10, "frames": 480, "scenes": ["fresh_hm_00"], "seeds": 5,
        "navigable_m2": {"fresh_hm_00": 101.5}}


def test_a_results_file_with_an_unreadable_episode_is_refused_naming_it(tmp_path):
    """The episodes are read back: one missing a field, or with SPL out of [0, 1], is named with its index, scene and
    goal, and the check exits 2 without a traceback."""
    import json

    good = episodes({"orion": 0.5}, goals=2, seeds=1)
    for bad, said in ((dict(good[1], spl=1.5), "episode 1 (a/g1): field 'spl' is 1.5, expected a number in [0, 1]"),
                      ({k: v for k, v in good[1].items() if k != "seed"},
                       "episode 1 (a/g1): field 'seed' is None, expected an int"),
                      (dict(good[1], success="yes"), "episode 1 (a/g1): field 'success' is 'yes', expected a bool")):
        path = tmp_path / "results.json"
        path.write_text(json.dumps({"episodes": [good[0], bad]}))
        out = run_check("--results", str(path), "--boot", "10")
        assert out.returncode == 2 and "Traceback" not in out.stderr and out.stdout == ""
        assert f"--results {path}: {said} (the episodes `zipon eval` writes)" in out.stderr


def test_episode_error_accepts_what_the_evaluator_writes(check):
    assert check.episode_error(episodes({"orion": 0.5, "cow": 1.0}, goals=2, seeds=2)) is None
    assert check.episode_error({"a": 1}) == "'episodes' is a dict, expected a list of episode records"
    assert check.episode_error([3]) == "episode 0 is a int, expected an object"


def test_every_field_the_episodes_are_read_with_has_its_expected_wording(check):
    from orion_eval.records import EpisodeOutcome

    assert set(check.EXPECTED) == set(EpisodeOutcome.model_fields)
