import pytest

from zipon.cli import main

from tests.pipeline.project.conftest import git


@pytest.mark.slow
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


@pytest.mark.slow
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


def test_diff_of_versions_without_cards_compares_params_and_says_goals_were_not(tmp_path, capsys):
    """Two commits of a project never built: the params key is named, no stage was rebuilt, and the missing cards
    are said, not guessed."""
    from tests.pipeline.project.conftest import set_params

    root = tmp_path / "ds"
    assert main(["-q", "init", str(root)]) == 0
    git(root, "add", "-A")
    git(root, "commit", "-q", "-m", "a")
    set_params(root / "params.yaml", {"routes": {"episodes_per_goal": 5}})
    git(root, "commit", "-q", "-am", "b")
    capsys.readouterr()
    assert main(["-p", str(root / "params.yaml"), "diff", "HEAD~1", "HEAD"]) == 0
    lines = [line.strip() for line in capsys.readouterr().out.splitlines()]
    assert [line for line in lines if line.startswith("routes.")] == ["routes.episodes_per_goal 3 -> 5"]
    assert "stages rebuilt: none" in lines and "artifacts whose digests differ: none" in lines
    assert "HEAD~1 has no dataset.json (written by `zipon run` / `zipon card`): goals not compared" in " ".join(lines)
    outside = tmp_path / "loose"
    outside.mkdir()
    (outside / "params.yaml").write_text("scenes:\n  a: {source: simulate}\n")
    assert main(["-p", str(outside / "params.yaml"), "diff", "v1", "v2"]) == 1
    assert "is not inside a git repository" in capsys.readouterr().err
