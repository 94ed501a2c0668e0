import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.config import load_params, params_yaml, parse_params
from pipeline.dvcfile import render_dvc_yaml
from pipeline.manifest import Manifest
from pipeline.paths import Workspace
from pipeline.runner import staleness
from stages import STAGES

REPO = Path(__file__).resolve().parents[2]


def test_committed_dvc_yaml_matches_the_stage_registry():
    ws = Workspace.resolve(REPO / "params.yaml", REPO / "data", REPO / "manifests")
    expected = render_dvc_yaml(ws, load_params(ws.params_path), STAGES)
    assert (REPO / "dvc.yaml").read_text() == expected, "dvc.yaml is stale: run `zipon dvc`"


def test_committed_params_yaml_lists_every_tunable():
    committed = yaml.safe_load((REPO / "params.yaml").read_text())
    full = yaml.safe_load(params_yaml(load_params(REPO / "params.yaml")))
    assert committed == full, "params.yaml lacks keys (or has stale ones): regenerate with `zipon params --write`"


@pytest.mark.slow
def test_dvc_repro_runs_the_same_stages_offline(tmp_path):
    """`dvc repro` in a scratch project (code linked, tiny params) produces the artifacts and manifests
    `zipon status` then considers up to date."""
    for name in ("pipeline", "stages"):
        (tmp_path / name).symlink_to(REPO / name)
    raw = yaml.safe_load((REPO / "params.yaml").read_text())
    raw["scenes"] = {"t0": {"source": "simulate", "format": "auto"}}
    raw["simulate"].update(frames=6, width=160, height=120, rooms_min=2, rooms_max=3)
    params = parse_params(raw)
    (tmp_path / "params.yaml").write_text(params_yaml(params))
    ws = Workspace.resolve(tmp_path / "params.yaml", tmp_path / "data", tmp_path / "manifests")
    (tmp_path / "dvc.yaml").write_text(render_dvc_yaml(ws, params, STAGES))
    env = {k: v for k, v in os.environ.items() if k not in ("ZIPON_DATA", "ZIPON_MANIFESTS")}
    env.update(DVC_NO_ANALYTICS="1", PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}")
    dvc = [sys.executable, "-m", "dvc"]
    subprocess.run(dvc + ["init", "--no-scm", "-q"], cwd=tmp_path, env=env, check=True)
    subprocess.run(dvc + ["config", "core.analytics", "false"], cwd=tmp_path, env=env, check=True)
    done = subprocess.run(dvc + ["repro", "ingest@t0"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert Manifest.read(ws.manifest("t0", "ingest")).summary["matched_frames"] == 6
    for stage in ("simulate", "ingest"):
        assert staleness(ws, params, STAGES, STAGES[stage], "t0") == ""
    again = subprocess.run(dvc + ["status"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert "ingest@t0" not in again.stdout
