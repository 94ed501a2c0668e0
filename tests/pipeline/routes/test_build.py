"""The routes stage's work as a library call (:func:`pipeline.routes.build.build_routes`) on the hand-made house."""

import shutil

import numpy as np
import pytest
import zarr

from pipeline.config import GoalsParams, RoutesParams, TaskParams
from pipeline.errors import LineageError
from pipeline.frames import FrameStore
from pipeline.goals import store as goals_store
from pipeline.goals.build import build_scene_goals
from pipeline.goals.store import Goals
from pipeline.recon import Recon
from pipeline.routes import store as routes_store
from pipeline.routes.build import build_routes
from pipeline.routes.store import Routes
from pipeline.store import artifact_attrs
from tests.fixtures.goal_scenes import write_house_artifacts


@pytest.fixture(scope="module")
def house(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("house_routes")
    frames, recon = write_house_artifacts(tmp)
    build_scene_goals(FrameStore(frames), Recon(recon), tmp / "goals.zarr",
                      artifact_attrs(goals_store.ARTIFACT, goals_store.FORMAT_VERSION, "goals", "test"), scene="house",
                      goals=GoalsParams(), task=TaskParams(), root=tmp, log=lambda m: None)
    return tmp, Goals(tmp / "goals.zarr"), recon


def _attrs():
    return artifact_attrs(routes_store.ARTIFACT, routes_store.FORMAT_VERSION, "routes", "test", scene="house")


def test_build_routes_writes_replay_verified_episodes_and_reports_progress(house):
    tmp, goals, recon = house
    seen = []

    def progress(items, total, description):
        seen.append((total, description))
        return items

    summary = build_routes(goals, Recon(recon), tmp / "routes.zarr", _attrs(), RoutesParams(episodes_per_goal=1),
                           TaskParams(), log=lambda m: None, progress=progress)
    routes = Routes(tmp / "routes.zarr")
    assert summary["goals"] == len(goals.goals) == 10 and summary["unreachable_goals"] == 0
    assert summary["episodes"] == len(routes.episodes) == 10 and summary["replay_verified_share"] == 1.0
    assert seen == [(10, "episodes")]
    assert summary["mean_geodesic_m"] == pytest.approx(np.mean([e.geodesic_m for e in routes.episodes]), abs=1e-3)


def test_goals_on_another_grid_than_recon_are_a_lineage_error(house, tmp_path):
    _, goals, recon = house
    moved = tmp_path / "recon.zarr"
    shutil.copytree(recon, moved)
    group = zarr.open_group(moved, mode="r+")
    grid = dict(group.attrs["grid"])
    grid["origin_xy"] = [grid["origin_xy"][0] + 1.0, grid["origin_xy"][1]]  # recon rebuilt on a shifted grid
    group.attrs["grid"] = grid
    with pytest.raises(LineageError, match="goals grid .* differs from recon grid .*; rerun the goals stage"):
        build_routes(goals, Recon(moved), tmp_path / "routes.zarr", _attrs(), RoutesParams(), TaskParams(),
                     log=lambda m: None)
    assert not (tmp_path / "routes.zarr").exists()


def test_routes_read_the_goal_regions_stored_with_the_goals(house, tmp_path):
    tmp, goals, recon = house
    assert goals.success_m == TaskParams().success_m and goals.attrs["goal_region"]["success_m"] == 1.5
    regions = [goals.goal_region(g.id) for g in goals.goals]
    assert all(r.any() for r in regions) and goals.goal_region("no such goal").sum() == 0
    routes = Routes(tmp / "routes.zarr")  # written by the first test of this module
    for e in routes.episodes:
        end = goals.grid.world_to_cell(e.path_xy[-1])
        assert regions[[g.id for g in goals.goals].index(e.goal_id)][end[0], end[1]]
    # another success radius than the regions were cut with: the goals are stale
    with pytest.raises(LineageError, match=r"goal regions cut with success_m 1\.5, but task\.success_m is 1\.4; "
                                           r"rerun the goals stage"):
        build_routes(goals, Recon(recon), tmp_path / "routes.zarr", _attrs(), RoutesParams(),
                     TaskParams(success_m=1.4, stop_radius_m=0.9), log=lambda m: None)
    assert not (tmp_path / "routes.zarr").exists()
