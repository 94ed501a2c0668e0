"""Goals and episodes of a building, built on the reconstructed two-storey house (a straight stair along its south
wall; a table on each floor): the upper table's procedural feedback climbs the stairs from the recording's start,
the routes stage adds verified episodes from the other floor whose replay, leg by leg, reaches the goal, and a
single-floor scene's stores carry none of a building's keys."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from pipeline.config import GoalsParams, GridParams, ReconstructParams, RoutesParams, TaskParams
from pipeline.frames import FrameStore
from pipeline.goals import store as goals_store
from pipeline.goals.build import build_scene_goals
from pipeline.goals.store import Goals
from pipeline.nav.actions import RouteSettings
from pipeline.nav.building import STAIR_END_RADIUS_M, building_planner
from pipeline.nav.verify import replay
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from pipeline.routes import store as routes_store
from pipeline.routes.build import build_routes
from pipeline.routes.store import Routes
from pipeline.store import artifact_attrs
from tests.fixtures.recon_scenes import STOREY_M, write_two_storey_frames

OBJECTS = {
    "rooms": [{"id": "hall_0", "type": "living room", "polygon": [[0, 0], [6, 0], [6, 4], [0, 4]]},
              {"id": "hall_1", "type": "bedroom", "polygon": [[0, 1], [6, 1], [6, 4], [0, 4]], "floor": 1}],
    "objects": [
        {"key": "table_0", "cls": "table", "instance_id": 1, "room": "hall_0",
         "footprint": [[1.0, 2.2], [2.0, 2.2], [2.0, 3.0], [1.0, 3.0]], "mass_center": [1.5, 2.6],
         "z_range": [0.0, 0.75], "color_name": "brown", "material": "wood"},
        {"key": "table_1", "cls": "table", "instance_id": 2, "room": "hall_1", "floor": 1,
         "footprint": [[3.5, 2.2], [4.5, 2.2], [4.5, 3.0], [3.5, 3.0]], "mass_center": [4.0, 2.6],
         "z_range": [0.0, 0.75], "color_name": "brown", "material": "wood"},
    ],
}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("building")
    frames, _ = write_two_storey_frames(tmp / "frames.zarr")
    reconstruct(frames, tmp / "recon.zarr", tmp / "mesh.ply", tmp / "points.ply", ReconstructParams(),
                GridParams(rows=160, cols=200))
    (tmp / "objects.yaml").write_text(yaml.safe_dump(OBJECTS))
    recon = Recon(tmp / "recon.zarr")
    goals_params = GoalsParams(objects="file", objects_files={"house": "objects.yaml"}, max_goals=10)
    build_scene_goals(FrameStore(frames), recon, tmp / "goals.zarr",
                      artifact_attrs(goals_store.ARTIFACT, goals_store.FORMAT_VERSION, "goals", "test"),
                      scene="house", goals=goals_params, task=TaskParams(), root=tmp, log=lambda m: None)
    summary = build_routes(Goals(tmp / "goals.zarr"), recon, tmp / "routes.zarr",
                           artifact_attrs(routes_store.ARTIFACT, routes_store.FORMAT_VERSION, "routes", "test",
                                          scene="house"),
                           RoutesParams(episodes_per_goal=2, cross_floor_per_goal=2, min_geodesic_m=1.0),
                           TaskParams(), log=lambda m: None)
    return tmp, recon, Goals(tmp / "goals.zarr"), Routes(tmp / "routes.zarr"), summary


def test_each_goal_lies_on_its_floor_and_its_region_on_that_floors_grid(built):
    _, recon, goals, _, _ = built
    assert len(recon.floors) == 2 and len(recon.stairs) == 1
    assert [f["id"] for f in goals.floors] == [0, 1]
    assert {g.id: g.floor for g in goals.goals} == {"table_0": 0, "table_1": 1}
    for g in goals.goals:
        region = goals.goal_region(g.id)
        assert region.any() and not (region & ~recon.floor(g.floor).navigable).any()
        # each floor's footprint raster holds that floor's table only
        assert goals.footprint_mask(g.object_keys).any()
        assert not (goals.object_index(1 - g.floor) == goals.object_keys.index(g.object_keys[0]) + 1).any()


def test_the_upper_goals_procedural_feedback_climbs_the_stairs_from_the_start(built):
    _, _, goals, _, _ = built
    upper = goals.goal("table_1").feedback["procedural"]
    assert upper is not None and "go up the stairs" in upper, upper
    lower = goals.goal("table_0").feedback["procedural"]
    assert lower is None or "stairs" not in lower


def test_cross_floor_episodes_replay_leg_by_leg_into_the_goal_region(built):
    _, recon, goals, routes, summary = built
    assert summary["floors"] == 2 and summary["cross_floor_episodes"] >= 2
    cross = [e for e in routes.episodes if len(e.floors) > 1]
    assert {e.goal_id for e in cross} == {"table_0", "table_1"}
    building = building_planner(recon, RouteSettings.from_config(TaskParams()))
    stair = building.links[0]
    for e in cross:
        goal = goals.goal(e.goal_id)
        assert e.floors == (e.start_floor, goal.floor) and e.start_floor != goal.floor
        assert ("go up the stairs" if goal.floor == 1 else "go down the stairs") in e.instruction
        # the reference length goes through the stair: at least its length along the slope
        assert e.geodesic_m >= math.hypot(stair.run_m, STOREY_M) - 0.5
        # the stored walk, piece by piece: the first leg ends at the stair's end on the start floor, the climb walks
        # the stair's run, the last leg from the stair's other end ends in the goal region facing the goal
        stored = routes.records[routes.episodes.index(e)]
        n0, climb, n1 = stored.segments
        assert n0 + climb + n1 == len(e.actions) and e.actions[-1] == 0
        first, last = recon.floor(e.start_floor), recon.floor(goal.floor)
        end0 = replay(e.actions[:n0], e.start, first.navigable, first.grid, [])
        near, far = stair.end_on(e.start_floor), stair.end_on(goal.floor)
        rc = first.grid.world_to_cell(np.asarray(end0.final_xyyaw[:2]))
        assert end0.collisions == 0 and building.stair_end_cells(stair, e.start_floor)[rc[0], rc[1]]  # a cell at the stair
        assert math.dist(end0.final_xyyaw[:2], near) <= STAIR_END_RADIUS_M + first.grid.cell_size_m
        assert np.count_nonzero(e.actions[n0:n0 + climb] == 1) == math.ceil(stair.run_m / 0.25 - 1e-9)
        end1 = replay(e.actions[n0 + climb:], (*far, math.atan2(far[1] - near[1], far[0] - near[0])),
                      last.navigable, last.grid, list(goal.footprints), region=goals.goal_region(goal.id),
                      face_xy=goal.mass_centers, hfov_deg=TaskParams().hfov_deg)
        assert end1.success
        stored = routes.records[routes.episodes.index(e)]
        assert sum(stored.leg_points) == len(e.path_xy) and math.dist(e.path_xy[0], e.start[:2]) < 0.2
    same = [e for e in routes.episodes if len(e.floors) == 1]
    assert len(same) >= 2 and all(e.floors == (goals.goal(e.goal_id).floor,) for e in same)


def test_a_single_floor_scenes_stores_carry_no_building_keys(tmp_path):
    from tests.fixtures.goal_scenes import write_house_artifacts

    frames, recon = write_house_artifacts(tmp_path)
    build_scene_goals(FrameStore(frames), Recon(recon), tmp_path / "goals.zarr",
                      artifact_attrs(goals_store.ARTIFACT, goals_store.FORMAT_VERSION, "goals", "test"), scene="house",
                      goals=GoalsParams(), task=TaskParams(), root=tmp_path, log=lambda m: None)
    build_routes(Goals(tmp_path / "goals.zarr"), Recon(recon), tmp_path / "routes.zarr",
                 artifact_attrs(routes_store.ARTIFACT, routes_store.FORMAT_VERSION, "routes", "test", scene="house"),
                 RoutesParams(episodes_per_goal=1), TaskParams(), log=lambda m: None)
    g = Goals(tmp_path / "goals.zarr")
    assert "floors" not in g.attrs and "region_floors" not in g.attrs and "floors" not in g.group
    assert all("floor" not in o for o in g.attrs["objects"])
    r = Routes(tmp_path / "routes.zarr")
    assert all(k not in rec for rec in r.attrs["episodes"] for k in ("start_floor", "floors", "leg_points"))
    assert np.all([e.floors == (0,) for e in r.episodes])


def test_a_building_episode_whose_legs_do_not_match_its_path_is_refused_naming_it(built, tmp_path):
    import shutil

    import zarr

    from pipeline.errors import ArtifactError

    src = built[0] / "routes.zarr"
    copy = shutil.copytree(src, tmp_path / "routes.zarr")
    group = zarr.open_group(str(copy), mode="r+")
    episodes = group.attrs["episodes"]
    i = next(k for k, e in enumerate(episodes) if len(e.get("floors", [])) > 1)
    episodes[i]["leg_points"] = [episodes[i]["leg_points"][0] + 1, *episodes[i]["leg_points"][1:]]
    group.attrs["episodes"] = episodes
    with pytest.raises(ArtifactError, match=rf"routes.zarr: attrs.episodes\[{i}\] \('[^']+'\): leg_points .* add up to "
                                            r"\d+, not the episode's \d+ path points"):
        Routes(copy)
    assert len(Routes(src).episodes) == len(episodes)  # the store as built reads
