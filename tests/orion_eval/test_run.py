"""The evaluator (``orion_eval.run.evaluate``) end to end on the tiny scene: results, determinism, the report."""

import json
import os
import shutil
import subprocess
import time

import pytest

from orion_eval.run import evaluate
from stages import STAGES
from pipeline.errors import ConfigError

MAP_AGENTS = ("vlmap", "cf", "orion")
FEEDBACK = ("corrective", "descriptive", "landmark", "procedural", "mixed")


@pytest.fixture(scope="module")
def evaluated(tiny_scene, tmp_path_factory):
    ws, params = tiny_scene
    out = tmp_path_factory.mktemp("eval_out")
    res = evaluate(ws, params, STAGES, out, seeds=[0], progress=False)
    return ws, params, out, res


def test_results_document_and_logs(evaluated):
    ws, params, out, res = evaluated
    from orion_eval.agents import AGENTS
    from orion_eval.user import FEEDBACK_SETTINGS

    # eval.methods / eval.feedback unset: every registered agent evaluated by default (the paper's table order; the
    # LLM agent only when named), every setting
    assert params.eval.methods is None and params.eval.feedback is None
    assert res["run"]["methods"] == [m for m in AGENTS if AGENTS[m].by_default] == ["human", "cow", "vlmap", "cf",
                                                                                     "orion"]
    assert list(AGENTS)[-1] == "llm"
    assert res["run"]["feedback"] == list(FEEDBACK_SETTINGS)
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["overall"] == res["overall"]
    for method, row in res["overall"].items():
        for fb, cell in row.items():
            assert set(cell) >= {"SR", "SPL", "SIT"} and 0 <= cell["SPL"] <= cell["SR"] <= 100
            assert cell["SIT"] <= cell["SR"]
    ep = res["episodes"][0]
    assert {"success", "spl", "sit", "talk_turns", "travelled_m", "geodesic_m", "end"} <= set(ep)
    import gzip

    with gzip.open(out / "episodes" / "tiny.episodes.jsonl.gz", "rt") as f:
        first = json.loads(f.readline())
    log = first["log"]
    assert len(log["poses"]) == len(log["actions"]) + 1 and log["dialogue"][0]["speaker"] == "agent"


def test_upper_bound_and_feedback_ordering(evaluated):
    _, _, _, res = evaluated
    o = res["overall"]
    for fb in o["human"]:
        assert o["human"][fb]["SR"] >= 95.0
        assert o["human"][fb]["SIT"] == o["human"][fb]["SR"]  # one Talk turn
    exceptions = []
    for m in MAP_AGENTS:
        assert o[m]["none"]["SR"] <= o[m]["yesno"]["SR"], m
        for fb in FEEDBACK:
            if o[m]["yesno"]["SR"] > o[m][fb]["SR"]:
                exceptions.append((m, fb))
                # Known exceptions (reported), both of a reply with a route: a route moves the agent, so it
                # approaches a candidate from another side, where the map candidate's centre is in sight but the
                # goal's mass centre is not; and a pointed destination the agent cannot reach (off the map) leaves
                # it where the walk stopped, whose candidates then come first (a map without a detector orders its
                # landmark tiers within each metre of the route's end: cabinet_3's mixed episode asks round where
                # it stopped instead of next to the landmarks). At most one episode of a cell may flip that way.
                one = 100.0 / o[m][fb]["episodes"]
                assert o[m]["yesno"]["SR"] - o[m][fb]["SR"] <= one + 1e-6, (m, fb)
    assert all(fb in ("procedural", "mixed") for _, fb in exceptions), exceptions
    for e in res["episodes"]:
        if e["feedback"] == "none":
            assert e["talk_turns"] <= 1
        assert e["talk_turns"] <= 5


def test_same_seed_same_results(tiny_scene, tmp_path):
    ws, params = tiny_scene
    kw = dict(methods=["cow", "orion"], feedback=["mixed"], seeds=[1], progress=False, report=False)
    a = evaluate(ws, params, STAGES, tmp_path / "a", **kw)
    b = evaluate(ws, params, STAGES, tmp_path / "b", **kw)
    strip = lambda r: [{k: v for k, v in e.items() if k != "seconds"} for e in r["episodes"]]
    assert strip(a) == strip(b) and a["overall"] == b["overall"]
    assert (tmp_path / "a" / "episodes" / "tiny.episodes.jsonl.gz").read_bytes() != b""


def test_results_name_the_artifacts_evaluated_and_any_stage_that_lags(evaluated, tiny_scene, tmp_path, capsys):
    from pipeline.engine.manifest import Manifest

    ws, params, _, res = evaluated
    for stage, name in (("reconstruct", "recon"), ("vlmap", "vlmap"), ("goals", "goals"), ("routes", "routes")):
        assert res["run"]["artifacts"]["tiny"][name] == Manifest.read(ws.manifest("tiny", stage)).outputs[name].digest
    assert res["run"]["stale"] == {}

    # the goals' params changed since they were built: evaluated as built, and the results and stderr say so
    changed = params.model_copy(update={"goals": params.goals.model_copy(update={"max_goals": 9})})
    capsys.readouterr()
    res = evaluate(ws, changed, STAGES, tmp_path, methods=["cow"], feedback=["yesno"], seeds=[0], progress=False,
                   report=False)
    assert list(res["run"]["stale"]) == ["tiny/goals"] and "goals.max_goals 8 -> 9" in res["run"]["stale"]["tiny/goals"]
    err = capsys.readouterr().err
    assert "lag their code, params or inputs" in err and "tiny/goals: params: goals.max_goals 8 -> 9" in err
    from orion_eval.report import run_notes

    assert any(line.startswith("Evaluated as built") and "tiny/goals" in line for line in run_notes(res["run"]))


def test_unknown_names_are_config_errors(tiny_scene, tmp_path):
    ws, params = tiny_scene
    with pytest.raises(ConfigError, match="--methods: unknown method"):
        evaluate(ws, params, STAGES, tmp_path, methods=["gpt"], progress=False)
    with pytest.raises(ConfigError, match="--feedback: unknown setting"):
        evaluate(ws, params, STAGES, tmp_path, feedback=["shouting"], progress=False)
    with pytest.raises(ConfigError, match="--scene: unknown scene"):
        evaluate(ws, params, STAGES, tmp_path, scenes=["nope"], progress=False)
    named = params.model_copy(update={"eval": params.eval.model_copy(update={"methods": ("cow", "gpt"),
                                                                            "feedback": ("shouting",)})})
    with pytest.raises(ConfigError, match=r"eval\.methods: unknown method\(s\) \['gpt'\]; choose from \['human', "):
        evaluate(ws, named, STAGES, tmp_path, progress=False)
    with pytest.raises(ConfigError, match=r"eval\.feedback: unknown setting\(s\) \['shouting'\]"):
        evaluate(ws, named, STAGES, tmp_path, methods=["cow"], progress=False)


def test_report_renders_in_headless_chromium(evaluated, tmp_path):
    _, _, out, _ = evaluated
    page = (out / "report.html").read_text()
    assert "Table I" in page and "success_by_turn.png" in page and (out / "success_by_turn.png").stat().st_size > 5000
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        pytest.skip("chromium is not installed (apt-get install -y chromium): the HTML report was written but "
                    "not rendered to PNG")
    png = tmp_path / "report.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", f"--screenshot={png}",
                    "--window-size=1200,1600", (out / "report.html").as_uri()], check=True, timeout=120,
                   capture_output=True)
    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape[:2] == (1600, 1200)
    assert (img < 200).mean() > 0.01  # text, tables and the figures are drawn, not a blank page


def test_zipon_eval_refuses_a_method_no_registry_has(tiny_scene, tmp_path, capsys):
    from zipon.cli import main

    ws, _ = tiny_scene
    text = ws.params_path.read_text().replace("eval: {workers: 1,", "eval: {methods: [cow, gpt], workers: 1,")
    assert "methods: [cow, gpt]" in text
    (tmp_path / "params.yaml").write_text(text)
    code = main(["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), "eval", "-o", str(tmp_path / "out")])
    assert code == 1
    err = " ".join(capsys.readouterr().err.split())
    assert ("eval.methods: unknown method(s) ['gpt']; choose from ['human', 'cow', 'vlmap', 'cf', 'orion', "
            "'orion_wo_mem', 'orion_wo_exp', 'orion_wo_det', 'orion_wo_map']") in err
    assert not (tmp_path / "out" / "results.json").exists()


def test_scene_caches_do_not_change_episodes(tiny_scene):
    """Routes, verdicts, views and detections cached while other settings ran give the same episodes as a scene
    context that saw only this setting."""
    from orion_eval.run import evaluate_scene

    ws, params = tiny_scene
    strip = lambda rs, fb: [{k: v for k, v in e.items() if k != "seconds"} for e in rs if e["feedback"] == fb]  # noqa: E731
    shared = evaluate_scene(ws, params, STAGES, "tiny", ["cow", "orion"], ["yesno", "procedural"], [0])
    alone = evaluate_scene(ws, params, STAGES, "tiny", ["cow", "orion"], ["procedural"], [0])
    assert strip(shared, "procedural") == strip(alone, "procedural") and len(alone) > 0


def test_feedback_settings_are_paired(tiny_scene):
    """Episodes of one (seed, goal) in 'procedural' and 'mixed' hear the same route at their first question (the
    agent asks it at the same place in both, before any feedback): the user's draws do not depend on the setting."""
    from orion_eval.run import evaluate_scene

    ws, params = tiny_scene
    eps = evaluate_scene(ws, params, STAGES, "tiny", ["vlmap"], ["procedural", "mixed"], [0, 1])
    first = {}
    for e in eps:
        talk = e["log"]["dialogue"]
        if len(talk) > 1 and talk[1]["kind"] != "yes":
            first[(e["feedback"], e["seed"], e["goal"])] = (talk[0]["pose"], talk[1]["text"], talk[1]["kind"])
    compared = 0
    for (fb, seed, goal), (pose, text, kind) in first.items():
        if fb != "procedural" or kind != "procedural":
            continue
        m_pose, m_text, m_kind = first[("mixed", seed, goal)]
        assert m_pose == pose and m_kind.endswith("procedural") and m_text.endswith(" " + text.removeprefix("No. "))
        compared += 1
    assert compared


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def test_scenes_are_handed_to_every_worker():
    """Two workers run one of two tasks each (each task outlasts a worker's start): dask's process scheduler otherwise
    hands a worker 6 tasks at once, and a 2-worker evaluation of up to 6 scenes ran them all in one process."""
    from orion_eval.run import map_processes

    pids = map_processes(_pid_after, [(2.0,), (2.0,)], 2)
    assert len(set(pids)) == 2 and os.getpid() not in pids


def test_a_building_runs_cross_floor_episodes_and_reports_them_apart(tiny_house, tmp_path, capsys):
    """On the tiny two-storey house the evaluator runs episodes that start on the goal's floor and on the other
    one (seeds take them in turn), the ground-truth follower reaches the cross-floor goals over the stairs, and the
    results and the report give the cross-floor episodes apart."""
    import gzip

    ws, params = tiny_house
    res = evaluate(ws, params, STAGES, tmp_path, methods=["human", "vlmap"], feedback=["procedural", "landmark"],
                   seeds=[0, 1], progress=False)
    eps = res["episodes"]
    cross = [e for e in eps if e["cross_floor"]]
    assert cross and len(cross) < len(eps)
    assert all(e["start_floor"] != e["goal_floor"] for e in cross)
    human = [e for e in cross if e["method"] == "human"]
    assert human and all(e["success"] and e["final_floor"] == e["goal_floor"] for e in human)
    assert all(0 < e["spl"] <= 1 for e in human)
    floors = res["by_floors"]
    assert set(floors["human"]) == {"same floor", "cross floor"} and floors["human"]["cross floor"]["procedural"][
        "SR"] == 100.0
    with gzip.open(tmp_path / "episodes" / "house.episodes.jsonl.gz", "rt") as f:
        logs = [json.loads(line) for line in f]
    walked = next(e for e in logs if e["method"] == "human" and e["cross_floor"])["log"]
    assert len(walked["floors"]) == len(walked["poses"]) and walked["floors"][0] != walked["floors"][-1]
    assert any(ev[1] == "stairs" for ev in walked["events"])
    html = (tmp_path / "report.html").read_text()
    assert "(cross floor, " in html and "(same floor, " in html
    # the scene's page draws each floor on its own: plans, goals and routes per floor, queries on their goal's floor
    pictures = {p.name for p in (tmp_path / "scenes" / "house").glob("*.png")}
    assert {f"{what}_floor{k}.png" for what in ("plan", "goals", "routes") for k in (0, 1)} <= pictures
    assert not {"plan.png", "goals.png", "routes.png"} & pictures
    page = (tmp_path / "scenes" / "house.html").read_text()
    assert "verified routes on floor 1" in page and "ground-truth floor plan of " in page
    from zipon.cli.common import print_eval

    print_eval(res, tmp_path)  # what zipon eval and zipon demo print
    printed = capsys.readouterr().out
    assert "buildings" in printed and "cross floor" in printed and "same floor" in printed
