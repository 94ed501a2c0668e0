"""The evaluator's tests run on the session's start-to-finish scene (tests/conftest.py: ``built_scene``)."""

import pytest


@pytest.fixture(scope="session")
def tiny_scene(built_scene):
    """``(Workspace, Params)`` of a workspace whose scene 'tiny' has every artifact and manifest."""
    return built_scene


HOUSE_PARAMS = """\
scenes:
  house: {source: simulate, building: {kind: house, stories: 2}}
simulate: {frames: 160, width: 160, height: 120}
reconstruct: {voxel_size_m: 0.05}
encoders: {simulated: oracle, oracle: {out_size: [30, 40]}}
goals: {max_goals: 6}
routes: {episodes_per_goal: 1, cross_floor_per_goal: 3}
eval: {workers: 1, seeds: [0, 1]}
"""


@pytest.fixture(scope="session")
def tiny_house(tmp_path_factory):
    """``(Workspace, Params)`` of a simulated two-storey house built by ``zipon run`` (every stage, real code, small
    images, the oracle encoder); tests must not modify its artifacts."""
    from tests.conftest import run_workspace

    return run_workspace(tmp_path_factory.mktemp("house_eval_ws"), HOUSE_PARAMS)
