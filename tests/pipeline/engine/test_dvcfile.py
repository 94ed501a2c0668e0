import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.paramsfile import load_params, params_yaml, parse_params
from pipeline.engine.dvcfile import dvc_files_problems, render_dvc_yaml, write_dvc_files
from pipeline.engine.manifest import Manifest
from pipeline.paths import Workspace
from pipeline.engine.stagegraph import staleness
from stages import STAGES

REPO = Path(__file__).resolve().parents[3]


def test_committed_dvc_yaml_matches_the_stage_registry():
    ws = Workspace.resolve(REPO / "params.yaml", REPO / "data", REPO / "manifests")
    expected = render_dvc_yaml(ws, load_params(ws.params_path), STAGES)
    assert (REPO / "dvc.yaml").read_text() == expected, "dvc.yaml is stale: run `zipon dvc`"


def test_committed_params_yaml_lists_every_tunable():
    committed = yaml.safe_load((REPO / "params.yaml").read_text())
    full = yaml.safe_load(params_yaml(load_params(REPO / "params.yaml")))
    assert committed == full, "params.yaml lacks keys (or has stale ones): regenerate with `zipon params --write`"


def _dvc_project(tmp_path, scenes: dict, frames: int = 6, **sections):
    """A scratch git + DVC project outside zipon's checkout: a tiny params.yaml, dvc.yaml rendered from it and the
    stages' code identity files."""
    raw = yaml.safe_load((REPO / "params.yaml").read_text())
    raw["scenes"] = scenes
    raw["simulate"].update(frames=frames, width=160, height=120, rooms_min=2, rooms_max=2)
    raw["grid"].update(rows=240, cols=240)
    raw["routes"].update(episodes_per_goal=1)
    raw["goals"].update(max_goals=3)
    for name, values in sections.items():
        raw[name].update(values)
    params = parse_params(raw)
    (tmp_path / "params.yaml").write_text(params_yaml(params))
    ws = Workspace.resolve(tmp_path / "params.yaml", tmp_path / "data", tmp_path / "manifests")
    write_dvc_files(ws, params, STAGES)
    env = {k: v for k, v in os.environ.items() if k not in ("ZIPON_DATA", "ZIPON_MANIFESTS")}
    env.update(DVC_NO_ANALYTICS="1", PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}")
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, env=env, check=True)
    subprocess.run([sys.executable, "-m", "dvc", "init", "-q"], cwd=tmp_path, env=env, check=True)
    subprocess.run([sys.executable, "-m", "dvc", "config", "core.analytics", "false"], cwd=tmp_path, env=env, check=True)
    return ws, params, env


def _dvc(tmp_path, env, *args):
    done = subprocess.run([sys.executable, "-m", "dvc", *args], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def _dvc_stale(tmp_path, env) -> set[str]:
    """Stage names `dvc status` lists as changed, as 'scene/stage'."""
    out = _dvc(tmp_path, env, "status")
    names = {line.strip().rstrip(":") for line in out.splitlines() if not line.startswith(("\t", " ")) and "@" in line}
    return {f"{n.split('@')[1]}/{n.split('@')[0]}" for n in names}


def _zipon_stale(ws, params) -> set[str]:
    from pipeline.engine.stagegraph import plan

    return {f"{scene}/{stage}" for scene, stage in plan(STAGES, params, list(params.scenes))
            if staleness(ws, params, STAGES, STAGES[stage], scene)}


@pytest.mark.slow
def test_zipon_run_leaves_dvc_with_nothing_to_do_and_both_name_the_same_stale_stages(tmp_path, capsys):
    """After `zipon run`, `dvc status` is clean and `dvc repro` runs nothing; after a params change both name
    the same stale stages."""
    from zipon.cli import main

    ws, params, env = _dvc_project(tmp_path, {"t0": {"source": "simulate"}}, frames=60,
                                   reconstruct={"voxel_size_m": 0.05}, encoders={"oracle": {"out_size": [30, 40]}})
    maps = [a for s in ("simulate", "ingest", "reconstruct", "vlmap", "cfmap") for a in ("--stage", s)]
    assert main(["-p", str(ws.params_path), "run", *maps]) == 0
    assert (tmp_path / "dvc.lock").is_file()
    shown = capsys.readouterr()
    assert "Updating lock file" not in shown.out + shown.err  # DVC's own line per stage: kept to -vv
    assert "dvc.lock: recorded 5 stage(s)" in " ".join((shown.out + shown.err).split())
    assert _dvc_stale(tmp_path, env) == {"t0/goals", "t0/routes"} == _zipon_stale(ws, params)  # never run
    repro = _dvc(tmp_path, env, "repro", "cfmap@t0", "vlmap@t0")
    assert "Running stage" not in repro, repro
    # a map setting: both maps and nothing else; a query/runtime setting: nothing
    text = ws.params_path.read_text()
    edited = text.replace("  level_height_m: 0.1\n", "  level_height_m: 0.2\n")
    edited = edited.replace("  min_candidate_score: 0.7\n", "  min_candidate_score: 0.5\n")
    edited = edited.replace("  encoder_batch_size: 4\n", "  encoder_batch_size: 2\n")
    assert edited.count("0.2\n") > text.count("0.2\n")
    ws.params_path.write_text(edited)
    params2 = load_params(ws.params_path)
    assert _zipon_stale(ws, params2) == {"t0/vlmap", "t0/cfmap", "t0/goals", "t0/routes"} == _dvc_stale(tmp_path, env)
    # a zipon upgrade that changed reconstruct's code: dvc.lock holds the identity an older zipon wrote; once
    # `zipon dvc` writes this zipon's, DVC names exactly that stage
    ws.params_path.write_text(text)
    identity = ws.code_id("reconstruct")
    current = identity.read_text()
    identity.write_text(current.replace('"code_digest": "blake2b:', '"code_digest": "blake2b:0ld'))
    _dvc(tmp_path, env, "commit", "-f", "reconstruct@t0")
    assert _dvc_stale(tmp_path, env) == {"t0/goals", "t0/routes"}
    assert main(["-p", str(ws.params_path), "dvc", "--check"]) == 1
    assert main(["-p", str(ws.params_path), "dvc"]) == 0 and identity.read_text() == current
    assert _dvc_stale(tmp_path, env) == {"t0/reconstruct", "t0/goals", "t0/routes"}


@pytest.mark.slow
def test_dvc_repro_runs_the_same_stages_offline(tmp_path):
    """`dvc repro` in a scratch project (code linked, tiny params) produces the artifacts and manifests
    `zipon status` then considers up to date."""
    ws, params, env = _dvc_project(tmp_path, {"t0": {"source": "simulate", "format": "auto"}})
    done = subprocess.run([sys.executable, "-m", "dvc", "repro", "ingest@t0"], cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert Manifest.read(ws.manifest("t0", "ingest")).summary["matched_frames"] == 6
    for stage in ("simulate", "ingest"):
        assert staleness(ws, params, STAGES, STAGES[stage], "t0") == ""
    assert "ingest@t0" not in _dvc(tmp_path, env, "status")


def test_a_folder_dvc_cannot_open_builds_and_says_why_dvc_lock_was_left(tmp_path, capsys):
    """A .dvc/ folder outside git (and without core.no_scm) is not a DVC project DVC can run: the run succeeds,
    says why dvc.lock was not written, and writes no dvc.yaml there."""
    from zipon.cli import main

    (tmp_path / ".dvc").mkdir()
    (tmp_path / "params.yaml").write_text("scenes:\n  a: {source: simulate}\n"
                                          "simulate: {frames: 4, width: 160, height: 120, rooms_min: 2, rooms_max: 2}\n")
    assert main(["-q", "-p", str(tmp_path / "params.yaml"), "run", "--stage", "simulate"]) == 0
    assert "dvc.lock not updated: DVC cannot open" in capsys.readouterr().err.replace("\n", " ")
    assert not (tmp_path / "dvc.yaml").exists() and not (tmp_path / "dvc.lock").exists()


def _deps(text: str) -> list[str]:
    stages = yaml.safe_load(text)["stages"]
    found = []
    for stage in stages.values():
        items = stage["foreach"] if isinstance(stage["foreach"], dict) else {s: {} for s in stage["foreach"]}
        for key, item in items.items():
            for dep in stage["do"]["deps"]:
                for name, value in item.items():
                    dep = dep.replace(f"${{item.{name}}}", value)
                found.append(dep.replace("${item}", key).replace("${key}", key))
    return found


@pytest.mark.parametrize("where", ["checkout", "project"])
def test_every_dependency_names_a_path_inside_the_project(tmp_path, where):
    """zipon's checkout and a project of its own (a recorded log inside it, a simulated scene): every dep of the
    generated dvc.yaml is a relative path that stays inside the project, and no stage names zipon's source."""
    if where == "checkout":
        ws = Workspace.resolve(REPO / "params.yaml", REPO / "data", REPO / "manifests")
        text = render_dvc_yaml(ws, load_params(ws.params_path), STAGES)
    else:
        (tmp_path / "raw").mkdir()
        (tmp_path / "raw" / "desk.mcap").write_bytes(b"")
        params = parse_params({"scenes": {"desk": {"source": "raw/desk.mcap"}, "sim": {"source": "simulate"}}})
        ws = Workspace.resolve(tmp_path / "params.yaml", tmp_path / "data", tmp_path / "manifests")
        text = render_dvc_yaml(ws, params, STAGES)
    deps = _deps(text)
    assert deps and all(not Path(d).is_absolute() and ".." not in Path(d).parts for d in deps), deps
    assert not [d for d in deps if d.endswith(".py")]
    assert {f".zipon/code/{s}.json" for s in STAGES} <= set(deps)


def test_code_identity_changes_for_exactly_the_stage_whose_code_changed(tmp_path, monkeypatch):
    """A zipon upgrade that changes one stage's code digest rewrites that stage's identity file only, and
    `dvc_files_problems` names it until then."""
    from pipeline.engine import dvcfile

    params = parse_params({"scenes": {"a": {"source": "simulate"}}})
    ws = Workspace.resolve(tmp_path / "params.yaml", tmp_path / "data", tmp_path / "manifests")
    written = write_dvc_files(ws, params, STAGES)
    assert {p.name for p in written} == {"dvc.yaml", *(f"{s}.json" for s in STAGES)}
    assert dvc_files_problems(ws, params, STAGES) == [] and write_dvc_files(ws, params, STAGES) == []
    held = yaml.safe_load(ws.code_id("goals").read_text())
    assert held["zipon_version"] and held["code_digest"].startswith("blake2b:")
    real = dvcfile.stage_code_digest
    monkeypatch.setattr(dvcfile, "stage_code_digest",
                        lambda spec: "blake2b:upgraded" if spec.name == "goals" else real(spec))
    problems = dvc_files_problems(ws, params, STAGES)
    assert len(problems) == 1 and problems[0].startswith(".zipon/code/goals.json: stage goals's code identity")
    assert held["code_digest"] in problems[0] and "blake2b:upgraded" in problems[0]
    assert write_dvc_files(ws, params, STAGES) == [ws.code_id("goals")]


def test_dvc_check_names_a_dvc_yaml_edited_by_hand(tmp_path, capsys):
    from zipon.cli import main

    (tmp_path / "params.yaml").write_text("scenes:\n  a: {source: simulate}\n")
    p = str(tmp_path / "params.yaml")
    assert main(["-p", p, "dvc"]) == 0
    path = tmp_path / "dvc.yaml"
    path.write_text(path.read_text().replace("      - .zipon/code/goals.json\n", "      - my_script.py\n"))
    capsys.readouterr()
    assert main(["-p", p, "dvc", "--check"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "dvc.yaml: differs from what zipon generates (line" in err and "'- my_script.py', expected " \
        "'- .zipon/code/goals.json'" in err and "edited by hand" in err and "zipon dvc" in err
    path.write_text(path.read_text().split("\n", 1)[1])  # the header gone too: only a hand could do that
    assert main(["-p", p, "dvc", "--check"]) == 1
    assert "(line 1: " in " ".join(capsys.readouterr().err.split())
    (tmp_path / ".zipon" / "code" / "routes.json").unlink()
    assert main(["-p", p, "dvc"]) == 0 and main(["-p", p, "dvc", "--check"]) == 0
    assert "routes.json" in capsys.readouterr().out
