"""The evaluation report: intervals, the bold rule, stable colours, autoescaping, and the scene page in Chromium."""

import re
import shutil
import subprocess

import numpy as np
import pytest

from orion_eval.agents.human import HumanAgent
from tests.fixtures.fresh_process import in_fresh_process
from orion_eval.agents.orion import OrionAgent
from orion_eval.metrics import summarize
from orion_eval.report import (cell_intervals, confidence_interval, is_upper_bound, method_color, method_name,
                               run_notes, write_report)


def _episodes(rates: dict[str, float], n: int = 10, feedback=("mixed",)) -> list[dict]:
    """Synthetic episode records: method m succeeds on the first round(rate * n) goals of each setting."""
    out = []
    for m, rate in rates.items():
        for fb in feedback:
            for i in range(n):
                ok = i < round(rate * n)
                out.append({"scene": "s0", "method": m, "feedback": fb, "seed": 0, "goal": f"g{i}",
                            "goal_type": "big" if i % 2 else "small", "episode": f"g{i}/0", "success": ok,
                            "spl": 0.8 if ok else 0.0, "sit": 0.5 if ok else 0.0, "talk_turns": 2 if ok else 5,
                            "steps": 10, "travelled_m": 3.0, "geodesic_m": 2.4, "collisions": 0, "end": "success",
                            "final_distance_m": 1.0})
    return out


def _results(rates, **kw) -> dict:
    eps = _episodes(rates, **kw)
    methods = list(rates)
    res = summarize(eps, methods=methods, feedback=list(kw.get("feedback", ("mixed",))), seeds=[0], scenes=["s0"])
    res["run"] = {"scenes": ["s0"], "methods": methods, "feedback": list(kw.get("feedback", ("mixed",))),
                  "seeds": [0], "episodes": len(eps), "seconds": 1.0, "episodes_per_s": len(eps),
                  "success_rule": "paper", "max_talk_turns": 5, "encoders": {"s0": {"vlmap": {"name": "oracle",
                                                                                        "diagnostic": True}}}}
    return res


def test_wilson_and_t_intervals():
    # 8 of 10: Wilson 95 % interval [0.490, 0.943]
    assert confidence_interval([1.0] * 8 + [0.0] * 2, "SR") == (49.0, 94.3)
    lo, hi = confidence_interval([0.0] * 10, "SR")
    assert lo == 0.0 and 25 < hi < 35  # no successes still leaves room above
    lo, hi = confidence_interval([0.5, 0.7, 0.6, 0.8], "SPL")
    assert lo < 65 < hi and lo == pytest.approx(100 * (0.65 - 3.182446 * np.std([.5, .7, .6, .8], ddof=1) / 2), abs=0.1)
    assert confidence_interval([], "SIT") is None
    cis = cell_intervals(_episodes({"orion": 0.8}), "method", "feedback")
    assert cis["orion"]["mixed"]["SR"] == (49.0, 94.3)


def test_bold_goes_to_the_best_method_that_is_not_an_upper_bound(tmp_path):
    html = write_report(_results({"human": 1.0, "vlmap": 0.4, "orion": 0.7}), tmp_path).read_text()
    table1 = html.split("Table I", 1)[1].split("Table II", 1)[0]
    human_row = table1.split("Human (GT route)", 1)[1].split("</tr>", 1)[0]
    orion_row = table1.split("ORION", 1)[1].split("</tr>", 1)[0]
    vlmap_row = table1.split("VLMap", 1)[1].split("</tr>", 1)[0]
    assert "<b>" not in human_row and "(upper bound)" in table1 and 'class="upper"' in table1
    assert orion_row.count("<b>") == 3 and "<b>" not in vlmap_row
    assert "<b>70.0</b>" in orion_row and "[39.7, 89.2]" in orion_row  # value and its Wilson interval
    assert '<td class="n">10</td>' in orion_row  # the cell's N
    for term in ("SR</dt>", "SPL</dt>", "SIT</dt>", "95 % CI</dt>"):
        assert term in html
    assert run_notes(_results({"orion": 0.5})["run"])[0].startswith("Maps built with the diagnostic oracle")
    assert run_notes({"methods": ["human", "cow", "orion"]}) == [
        "One controller for every method, each with its own modules (CoW: no map, saliency detection, exploration, "
        "no memory; ORION: map eval.orion_map, grounded detection, exploration, memory); the modules' error profiles come "
        "from published figures, none was set from these results."]
    assert (tmp_path / "scenes" / "s0.html").is_file() and 'href="scenes/s0.html"' in html


def test_method_colours_are_stable_and_names_escaped(tmp_path):
    # registered agents bring their own label, colour and upper-bound flag (one home: the agent class)
    assert method_color("orion") == OrionAgent.colour and method_name("human") == HumanAgent.label
    assert is_upper_bound("human") and not is_upper_bound("orion") and not is_upper_bound("my<agent>")
    # a method without its own colour gets one derived from its name: the same in another process (another string
    # hash seed: a colour from hash() would differ), different for other names
    names = ["my<agent>", "a", "b", "nearest_plugin"]
    mine = [method_color(n) for n in names]
    assert in_fresh_process("from orion_eval.report import method_color",
                            f"[method_color(n) for n in {names!r}]", hash_seed=7) == mine
    assert all(re.fullmatch(r"#[0-9a-f]{6}", c) for c in mine) and len(set(mine)) == len(names)
    html = write_report(_results({"my<agent>": 0.5, "orion": 0.2}), tmp_path).read_text()
    assert "my&lt;agent&gt;" in html and "my<agent>" not in html


def test_scene_page_with_pictures_and_episodes_renders_in_chromium(built_scene, tmp_path):
    from orion_eval.run import evaluate
    from stages import STAGES

    ws, params = built_scene
    evaluate(ws, params, STAGES, tmp_path, methods=["vlmap"], feedback=["mixed"], seeds=[0], progress=False)
    page = (tmp_path / "scenes" / "tiny.html").read_text()
    assert "Episode browser" in page and "episode_vlmap.png" in page and "goals.png" in page
    for name in ("goals.png", "routes.png", "episode_vlmap.png"):
        assert (tmp_path / "scenes" / "tiny" / name).stat().st_size > 5000, name
    assert list((tmp_path / "scenes" / "tiny").glob("query_vlmap_*.png"))
    assert "agent (step" in page and "user:" in page  # the dialogue
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        pytest.skip("chromium is not installed (apt-get install -y chromium)")
    png = tmp_path / "scene.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", f"--screenshot={png}",
                    "--window-size=1200,2400", (tmp_path / "scenes" / "tiny.html").as_uri()], check=True,
                   timeout=120, capture_output=True)
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape[:2] == (2400, 1200)
    # the pictures loaded: many distinct colours (a page of text and tables alone has a handful)
    assert len(np.unique(img[::4, ::4].reshape(-1, 3), axis=0)) > 2000


def test_per_setting_tests_are_listed_and_a_significant_best_sr_is_starred(tmp_path):
    res = _results({"human": 1.0, "vlmap": 0.2, "orion": 0.9}, n=30, feedback=("yesno", "none"))
    html = write_report(res, tmp_path).read_text()
    table1 = html.split("Table I", 1)[1].split("Table II", 1)[0]
    orion_row = table1.split("ORION", 1)[1].split("</tr>", 1)[0]
    assert orion_row.count("<sup>*</sup>") == 2 and "<sup>*</sup>" not in table1.split("VLMap", 1)[1].split("</tr>")[0]
    per_setting = html.split("per setting", 1)[1].split("Scenes", 1)[0]
    assert "VLMap vs ORION" in per_setting or "ORION vs VLMap" in per_setting
    assert "Human" not in per_setting  # upper bounds are not tested against the methods
