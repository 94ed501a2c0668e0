"""Stored human-answered episodes read back as user input: every record checked (file, line and field named),
records of goals a later edit removed left out with a warning or refused with strict, results.json always JSON."""

from __future__ import annotations

import json
import math

import pytest

from orion_eval.records import EpisodeRecord, read_human_episodes
from orion_eval.run import finite_json
from pipeline.errors import InputDataError

GOOD = {"scene": "tiny", "method": "cow", "feedback": "human", "seed": 0, "goal": "g0", "goal_type": "big",
        "episode": "e0", "success": True, "spl": 0.5, "sit": 1.0, "talk_turns": 1, "steps": 12, "travelled_m": 3.2,
        "geodesic_m": 1.6, "collisions": 0, "end": "found", "final_distance_m": 0.4, "log": {"dialogue": []}}


def write(tmp_path, *records) -> object:
    path = tmp_path / "tiny.episodes.jsonl"
    path.write_text("".join((r if isinstance(r, str) else json.dumps(r)) + "\n" for r in records))
    return path


def test_good_records_are_kept_and_others_scenes_and_methods_skipped(tmp_path):
    path = write(tmp_path, GOOD, {**GOOD, "method": "orion"}, "", {**GOOD, "scene": "other"})
    read = read_human_episodes(path, "tiny", {"g0"}, ["cow"])
    assert [r["method"] for r in read.records] == ["cow"] and read.dropped == {}
    assert EpisodeRecord.model_validate(read.records[0]).spl == 0.5


@pytest.mark.parametrize("change, line_field, words", [
    ({"spl": "0.5"}, "spl", "Input should be a valid number"),
    ({"talk_turns": 1.5}, "talk_turns", "valid integer"),
    ({"success": "yes"}, "success", "valid boolean"),
    ({"travelled_m": float("nan")}, "travelled_m", "finite number"),
    ({"spl": 3.0}, "spl", "less than or equal to 1"),
    ({"feedback": "mixed"}, "feedback", "Input should be 'human'"),
    ({"seed": -1}, "seed", "greater than or equal to 0"),
])
def test_a_wrong_field_is_named_with_the_file_and_the_line(tmp_path, change, line_field, words):
    path = write(tmp_path, GOOD, {**GOOD, **change})
    with pytest.raises(InputDataError) as err:
        read_human_episodes(path, "tiny", {"g0"}, ["cow"])
    text = str(err.value)
    assert f"file {path}" in text and f"field {line_field}" in text and "line 2" in text and words in text, text


@pytest.mark.parametrize("line, words", [('{"scene": ', "not a JSON episode record"), ("[1, 2]", "not a JSON object"),
                                         ('{"seed": ' + "9" * 5000 + "}", "not a JSON episode record"),
                                         ("[" * 100_000, "not a JSON episode record")])
def test_lines_that_are_not_records(tmp_path, line, words):
    path = write(tmp_path, GOOD, line)
    with pytest.raises(InputDataError, match=words) as err:
        read_human_episodes(path, "tiny", {"g0"}, ["cow"])
    assert "line 2" in str(err.value)


def test_a_missing_field_is_named(tmp_path):
    path = write(tmp_path, {k: v for k, v in GOOD.items() if k != "success"})
    with pytest.raises(InputDataError, match=r"field success: line 1: Field required"):
        read_human_episodes(path, "tiny", {"g0"}, ["cow"])


def test_episodes_of_removed_goals_are_left_out_or_refused_with_strict(tmp_path):
    path = write(tmp_path, GOOD, {**GOOD, "goal": "gone"}, {**GOOD, "goal": "gone"})
    read = read_human_episodes(path, "tiny", {"g0"}, ["cow"])
    assert len(read.records) == 1 and read.dropped == {"gone": 2}
    with pytest.raises(InputDataError, match=r"field goal: line 2: goal 'gone' is not in scene tiny's goals store"):
        read_human_episodes(path, "tiny", {"g0"}, ["cow"], strict=True)


def test_results_never_hold_nan():
    out = finite_json({"a": [1.0, float("nan"), (float("inf"), 2)], "b": {"c": -math.inf}, "d": "NaN"})
    assert out == {"a": [1.0, None, [None, 2]], "b": {"c": None}, "d": "NaN"}
    json.dumps(out, allow_nan=False)


def test_eval_leaves_out_removed_goals_with_a_warning_and_writes_strict_json(built_scene, tmp_path, capsys):
    from pipeline.goals.store import Goals
    from tests.zipon.annotate.conftest import copy_built
    from zipon.cli import main

    root = copy_built(built_scene[0], tmp_path / "ws")
    scene = next(iter(built_scene[1].scenes))
    first = Goals(root / "data" / "artifacts" / scene / "goals.zarr").goals[0].id
    path = root / "data" / "eval" / "human" / f"{scene}.episodes.jsonl"
    path.parent.mkdir(parents=True)
    record = {**GOOD, "scene": scene, "goal": first}
    write(path.parent, record, {**record, "goal": "gone"}, {**record, "goal": "gone"}).rename(path)
    code = main(["-q", "-p", str(root / "params.yaml"), "eval", "-s", scene, "-m", "cow", "-f", "human",
                 "--out", str(tmp_path / "ev")])
    err = " ".join(capsys.readouterr().err.split())
    assert code == 0, err
    assert f"left out the episodes of goals no longer in scene {scene}'s goals store: gone (2 episodes)" in err

    def no_constant(name):
        raise AssertionError(f"results.json holds {name}")

    results = json.loads((tmp_path / "ev" / "results.json").read_text(), parse_constant=no_constant)
    assert results["run"]["episodes"] == 1 and results["episodes"][0]["goal"] == first
