import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("DVC_NO_ANALYTICS", "1")

REPO = Path(__file__).resolve().parent.parent


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


@pytest.fixture(scope="session")
def built_scene(tmp_path_factory):
    """The start-to-finish run: a tiny simulated scene built by ``zipon run`` (every stage, real code).

    Returns ``(Workspace, Params)``; tests must not modify its artifacts.
    """
    from tests.fixtures.workspaces import zipon_built

    return zipon_built(tmp_path_factory.mktemp("smoke_ws"), TINY_PARAMS, "the tiny scene")


@pytest.fixture(scope="session")
def two_storey_maps(tmp_path_factory):
    """The two-storey house of :mod:`tests.fixtures.map_scenes` with its recon and both maps built, in a workspace:
    ``(Workspace, Params, ground truth, {stage: summary})``; tests must not modify its artifacts."""
    from tests.fixtures.map_scenes import build_two_storey_maps

    return build_two_storey_maps(tmp_path_factory.mktemp("house_ws"))
