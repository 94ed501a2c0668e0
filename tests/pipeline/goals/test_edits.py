"""``zipon goals import`` of a building's goals (pipeline/goals/edits.py): a goal whose objects lie on two floors is
refused naming the goal's field and each object's floor, and nothing is stored."""

from __future__ import annotations

import yaml

from pipeline.goals.store import Goals
from tests.zipon.annotate.conftest import copy_built
from zipon.cli import main


def test_a_goal_of_objects_on_two_floors_is_refused_and_nothing_stored(built_house, tmp_path, capsys):
    root = copy_built(built_house[0], tmp_path / "ws")
    base = ["-q", "-p", str(root / "params.yaml"), "--data-dir", str(root / "data"), "--manifests-dir",
            str(root / "manifests")]
    assert main([*base, "goals", "export", "house", "-o", str(tmp_path / "goals.yaml")]) == 0
    doc = yaml.safe_load((tmp_path / "goals.yaml").read_text())
    goals = Goals(root / "data" / "artifacts" / "house" / "goals.zarr")
    floor_of = {k: o.floor for k, o in goals.objects.items()}
    i = next(i for i, g in enumerate(doc["goals"]) if floor_of[g["objects"][0]] == 1)
    lower = next(k for k, f in floor_of.items() if f == 0 and k in doc["objects"])
    doc["goals"][i]["objects"].append(lower)
    (tmp_path / "edit.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    params_before = (root / "params.yaml").read_bytes()
    capsys.readouterr()
    assert main([*base, "goals", "import", "house", str(tmp_path / "edit.yaml")]) == 1
    err = capsys.readouterr().err
    assert f"field goals[{i}].objects" in err and f"{lower} (floor 0) lie on different floors" in err, err
    assert (root / "params.yaml").read_bytes() == params_before and not (root / "goals_edits").exists()
