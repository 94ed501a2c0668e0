"""The commands on built artifacts (zipon/cli/inspect.py) on the session's tiny scene: one consistent CLI."""

import json
import math

import numpy as np
import pytest

from zipon.cli import main


def cli(ws, *args) -> int:
    return main(["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), *args])


def _goal_class(ws):
    from pipeline.goals.store import Goals

    goals = Goals(ws.artifact("goals", "tiny"))
    return goals.objects[goals.goals[0].object_keys[0]].cls, goals


def test_query_pose_in_degrees_and_object_keys(built_scene, capsys):
    import zipon

    ws, _ = built_scene
    cls, goals = _goal_class(ws)
    x, y, _ = goals.attrs["start_pose"] or (0.0, 0.0, 0.0)
    capsys.readouterr()
    assert cli(ws, "query", "tiny", cls, "--pose", f"{x},{y},90", "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["pose_deg"][2] == pytest.approx(90.0) and doc["pose"][2] == pytest.approx(math.pi / 2)
    ref = zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)["tiny"].vlmap.query(
        cls, pose=(x, y, math.pi / 2))
    assert [c["angle_deg"] for c in doc["candidates"]] == [round(math.degrees(c.angle_rad), 3) for c in ref.candidates]
    keys = {o.instance_id: o.key for o in goals.objects.values()}
    hit = [c for c in doc["candidates"] if c["gt_instance"]]
    assert hit and all(c["gt_object"] == keys[c["gt_instance"]] for c in hit)
    assert any(keys[c["gt_instance"]].startswith(cls + "_") for c in hit)
    assert cli(ws, "query", "tiny", cls) == 0
    table = capsys.readouterr().out
    assert "angle (deg)" in table and f"{cls}_" in table and "#" not in table


def test_query_bad_inputs_exit_1_with_clear_messages(built_scene, capsys):
    ws, _ = built_scene
    capsys.readouterr()
    assert cli(ws, "query", "nope", "chair") == 1
    assert "unknown scene 'nope'" in capsys.readouterr().err
    assert cli(ws, "query", "tiny", "chair", "--pose", "1,2") == 1
    assert "field --pose: got '1,2' (expected x,y,yaw in metres, metres, degrees)" in capsys.readouterr().err
    assert cli(ws, "query", "tiny", "chair", "--pose", "1e4,0,0") == 1
    assert "lies off the map's grid" in capsys.readouterr().err
    assert cli(ws, "query", "tiny", "chair", "--map", "octomap") == 1
    assert "choose one of ['vlmap', 'cfmap']" in capsys.readouterr().err
    assert cli(ws, "render", "nope") == 1
    assert "unknown scene 'nope'" in capsys.readouterr().err
    assert cli(ws, "goals", "export", "nope", "-o", "nope.yaml") == 1
    assert "unknown scene 'nope'" in capsys.readouterr().err


def test_query_levels_top_or_max(built_scene, capsys):
    """``--levels max`` scores each cfmap cell by its best height level: never below its top level's probability."""
    from pipeline.maps.query import open_query

    ws, params = built_scene
    cls, _ = _goal_class(ws)
    docs = {}
    for levels in ("top", "max"):
        capsys.readouterr()
        assert cli(ws, "query", "tiny", cls, "--map", "cfmap", "--levels", levels, "--json") == 0
        docs[levels] = json.loads(capsys.readouterr().out)
        assert docs[levels]["levels"] == levels and docs[levels]["candidates"]
    heat = {}
    for levels in ("top", "max"):
        p = params.model_copy(update={"query": params.query.model_copy(update={"levels": levels})})
        heat[levels] = open_query(ws.artifact("cfmap", "tiny"), p).query(cls).heatmap
    seen = np.isfinite(heat["top"])
    assert (heat["max"][seen] >= heat["top"][seen] - 1e-6).all() and (heat["max"][seen] > heat["top"][seen]).any()
    assert cli(ws, "query", "tiny", cls, "--levels", "middle") == 1
    err = capsys.readouterr().err
    assert "query.levels" in err and "'top'" in err and "'max'" in err


def test_query_without_candidates_says_why(built_scene, capsys):
    ws, _ = built_scene
    capsys.readouterr()
    assert cli(ws, "query", "tiny", "purple elephant spaceship") == 0
    text = capsys.readouterr().out
    assert text.startswith("no candidates for 'purple elephant spaceship'"), text
    assert "<" in text and ("best score" in text or "best " in text or "area" in text)


def test_no_candidates_reason_names_the_threshold_that_failed():
    from zipon.cli.maps import no_candidates_reason
    from pipeline.config import QueryParams
    from pipeline.geometry import GridSpec
    from pipeline.maps.query import QueryResult

    grid = GridSpec(8, 8, 0.1, (0.0, 0.8))
    qp = QueryParams()

    def result(heat, wins):
        return QueryResult("sofa", "vlmap", grid, heat, wins, [], None, ["other"], 0.1, 0.0)

    heat = np.full((8, 8), np.nan, np.float32)
    assert no_candidates_reason(result(heat, np.zeros((8, 8), bool)), qp).endswith("the map has no observed cells")
    heat[:4, :4] = 0.31
    msg = no_candidates_reason(result(heat, np.zeros((8, 8), bool)), qp)
    assert "no cell beats the background prompts ['other'] with probability >= 0.5 (best 0.3100 < 0.5)" in msg
    heat[0, 0] = 0.8  # probable enough, yet no win: the query does not outscore every background prompt there
    msg = no_candidates_reason(result(heat, np.zeros((8, 8), bool)), qp)
    assert "(best 0.8000, but in no such cell does the query outscore every background prompt)" in msg
    heat[0, 0] = 0.31
    wins = np.zeros((8, 8), bool)
    wins[:3, :3] = True  # 0.09 m2, mean 0.31
    assert no_candidates_reason(result(heat, wins), qp) == "no candidates for 'sofa' (best score 0.31 < min 0.7)"
    tiny = np.zeros((8, 8), bool)
    tiny[0, 0] = True
    qp2 = qp.model_copy(update={"min_candidate_area_m2": 0.05})
    assert "largest winning area 0.010 m² < min 0.05 m²" in no_candidates_reason(result(heat, tiny), qp2)


def test_flags_take_no_value_in_help(built_scene, capsys):
    ws, _ = built_scene
    capsys.readouterr()
    assert cli(ws, "query", "--help") == 0
    line = next(li for li in capsys.readouterr().out.splitlines() if "--json" in li)
    assert "<bool>" not in line


def test_eval_seeds_is_a_count_and_seed_list_explicit(built_scene, tmp_path, capsys):
    ws, _ = built_scene
    common = ("-s", "tiny", "-m", "vlmap", "-f", "none")
    assert cli(ws, "eval", "-o", str(tmp_path / "a"), *common, "--seeds", "2") == 0
    assert json.loads((tmp_path / "a" / "results.json").read_text())["run"]["seeds"] == [0, 1]
    assert cli(ws, "eval", "-o", str(tmp_path / "b"), *common, "--seed-list", "3") == 0
    assert json.loads((tmp_path / "b" / "results.json").read_text())["run"]["seeds"] == [3]
    capsys.readouterr()
    assert cli(ws, "eval", "-o", str(tmp_path / "c"), *common, "--seeds", "1", "--seed-list", "3") == 1
    assert "exclude each other" in capsys.readouterr().err
    assert cli(ws, "eval", "-o", str(tmp_path / "c"), *common, "--seeds", "0") == 2  # usage error: min 1


def test_eval_runs_a_user_agent_by_module_and_class(built_scene, tmp_path, capsys):
    ws, _ = built_scene
    spec = "tests.fixtures.user_agents:NearestOnly"
    assert cli(ws, "eval", "-o", str(tmp_path), "-s", "tiny", "-m", spec, "-f", "yesno", "--seeds", "1") == 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["run"]["methods"] == ["nearest_only"] and res["overall"]["nearest_only"]["yesno"]["episodes"] > 0
    capsys.readouterr()
    assert cli(ws, "eval", "-o", str(tmp_path), "-m", "no_such_module:Agent") == 1
    assert "--method 'no_such_module:Agent': cannot import it" in capsys.readouterr().err
    assert cli(ws, "eval", "-o", str(tmp_path), "-m", "json:dumps") == 1
    assert "neither a method name nor a subclass" in capsys.readouterr().err


def test_goals_template_validates_and_matches_the_schema(built_scene, tmp_path, capsys):
    import jsonschema
    import yaml

    from pipeline.goals.objects import objects_from_file

    ws, _ = built_scene
    target = tmp_path / "objects.yaml"
    assert cli(ws, "goals", "template", "tiny", "-o", str(target)) == 0
    text = target.read_text()
    assert text.startswith("# zipon objects file for scene 'tiny'") and "#   footprint:" in text
    objs = objects_from_file(target, "tiny")
    _, goals = _goal_class(ws)
    assert {o.key for o in objs.objects} == set(goals.objects)
    capsys.readouterr()
    assert cli(ws, "goals", "schema", "--what", "objects") == 0
    schema = json.loads(capsys.readouterr().out)
    jsonschema.validate(yaml.safe_load(text), schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"objects": [{"key": "x"}]}, schema)
    assert cli(ws, "goals", "schema", "-o", str(tmp_path / "g.json")) == 0
    goals_schema = json.loads((tmp_path / "g.json").read_text())
    from pipeline.goals.schema import document_dict

    jsonschema.validate(document_dict(goals.document), goals_schema)
    assert cli(ws, "goals", "schema", "--what", "nope") == 1
    assert cli(ws, "goals", "template", "tiny", "-o", str(tmp_path / "x.json")) == 1
    assert "expected a .yaml file" in capsys.readouterr().err


def test_goals_template_for_a_scene_without_goals_places_an_example_in_the_map(tmp_path):
    from pipeline.goals.objects import objects_from_file
    from pipeline.goals.template import objects_template

    path = tmp_path / "t.yaml"
    path.write_text(objects_template("lab"))
    objs = objects_from_file(path, "lab")
    assert [o.key for o in objs.objects] == ["chair_0"] and objs.objects[0].mass_center == (0.0, 0.0)
