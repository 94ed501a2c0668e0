import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("DVC_NO_ANALYTICS", "1")

REPO = Path(__file__).resolve().parent.parent


def pytest_configure(config):
    """Under pytest-xdist, the tests that share a long build run on one worker (:mod:`tests.xdist_groups`)."""
    if config.pluginmanager.hasplugin("xdist"):
        from tests.xdist_groups import SharedBuilds

        config.pluginmanager.register(SharedBuilds(), "zipon-shared-builds")


@pytest.fixture
def workspace(tmp_path):
    """A fresh workspace (params.yaml, data/, manifests/) in a temp dir."""
    from pipeline.paths import Workspace

    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\n  s1: {source: simulate}\n")
    return Workspace.resolve(tmp_path / "params.yaml")


TINY_PARAMS = """\
scenes:
  tiny: {source: simulate}
simulate: {frames: 140, width: 160, height: 120, rooms_min: 3, rooms_max: 3}
reconstruct: {voxel_size_m: 0.05}
encoders: {simulated: oracle, oracle: {out_size: [30, 40]}}
maps: {cfmap_voxels: true}
goals: {max_goals: 8}
routes: {episodes_per_goal: 2}
eval: {workers: 1, seeds: [0, 1]}
"""


def run_workspace(root: Path, params_text: str):
    """``params_text`` written to ``root/params.yaml`` and every stage of its scenes built by ``zipon run`` (real
    code); returns ``(Workspace, Params)``."""
    from zipon.cli import main
    from pipeline.paramsfile import load_params
    from pipeline.paths import Workspace

    (root / "params.yaml").write_text(params_text)
    code = main(["-q", "-p", str(root / "params.yaml"), "--data-dir", str(root / "data"),
                 "--manifests-dir", str(root / "manifests"), "run"])
    assert code == 0, f"zipon run failed in {root}"
    ws = Workspace.resolve(root / "params.yaml", data_dir=root / "data", manifests_dir=root / "manifests")
    return ws, load_params(ws.params_path)


@pytest.fixture(scope="session")
def built_scene(tmp_path_factory):
    """The start-to-finish run: a tiny simulated scene built by ``zipon run`` (every stage, real code).

    Returns ``(Workspace, Params)``; tests must not modify its artifacts.
    """
    return run_workspace(tmp_path_factory.mktemp("smoke_ws"), TINY_PARAMS)


@pytest.fixture(scope="session")
def two_storey_maps(tmp_path_factory):
    """The two-storey house of :mod:`tests.fixtures.map_scenes` with its recon and both maps built, in a workspace:
    ``(Workspace, Params, ground truth, {stage: summary})``; tests must not modify its artifacts."""
    from tests.fixtures.map_scenes import build_two_storey_maps

    return build_two_storey_maps(tmp_path_factory.mktemp("house_ws"))


HOUSE_PARAMS = """\
scenes:
  house: {source: simulate, building: {kind: house, stories: 2}}
simulate: {frames: 180, width: 200, height: 150}
encoders: {simulated: oracle, oracle: {out_size: [30, 40]}}
goals: {max_goals: 8}
routes: {episodes_per_goal: 1}
eval: {workers: 1, seeds: [0]}
"""


@pytest.fixture(scope="session")
def built_house(tmp_path_factory):
    """A simulated two-storey house (rooms on both floors, one staircase) built by ``zipon run`` through every
    stage (about 40 s of CPU). Returns ``(Workspace, Params)``; tests must not modify its artifacts."""
    return run_workspace(tmp_path_factory.mktemp("house_built"), HOUSE_PARAMS)
