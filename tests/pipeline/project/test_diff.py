from zipon.cli import main

from tests.pipeline.project.conftest import git


def test_diff_names_params_stages_artifacts_and_goals_from_git_alone(dataset_versions, capsys):
    v = dataset_versions
    params = str(v.root / "params.yaml")
    assert main(["-p", params, "diff", "v1", "v2"]) == 0
    shown = capsys.readouterr().out
    lines = [line.strip() for line in shown.splitlines()]
    assert "goals.max_goals 3 -> 2" in lines
    assert "sim_00/goals: params: goals.max_goals 3 -> 2" in lines and "sim_00/routes: inputs changed: goals" in lines
    for artifact in ("goals", "routes"):
        a, b = v.digests["v1"][f"sim_00/{artifact}"], v.digests["v2"][f"sim_00/{artifact}"]
        assert f"sim_00/{artifact}: {a} -> {b}" in lines
    assert not [line for line in lines if line.startswith(("sim_00/frames", "sim_00/recon"))]
    removed = [line for line in lines if line.startswith("goals removed in sim_00: ")]
    assert len(removed) == 1 and removed[0].count("'") == 2  # the third goal, by id and name
    assert main(["-p", params, "diff", "v1", "v1"]) == 0
    assert "no difference in params, manifests or goals" in capsys.readouterr().out


def test_diff_json_and_bad_revisions(dataset_versions, capsys):
    import json

    v = dataset_versions
    params = str(v.root / "params.yaml")
    assert main(["-p", params, "diff", "v2", "v1", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["params"] == ["goals.max_goals 2 -> 3"] and len(d["goals"]["sim_00"]["added"]) == 1
    assert {(r["scene"], r["stage"]) for r in d["stages_rebuilt"]} == {("sim_00", "goals"), ("sim_00", "routes")}
    assert d["b"]["commit"] == git(v.root, "rev-parse", "v1").strip()
    assert main(["-p", params, "diff", "v1", "v9"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "v9: not a revision of the git repository at" in err and "(tags: v1, v2;" in err
    first = git(v.root, "rev-list", "--max-parents=0", "HEAD").strip()
    assert main(["-p", params, "diff", first + "~1", "v1"]) == 1
