import numpy as np
import pytest

from pipeline.nav.actions import (FORWARD, LEFT, RIGHT, STOP, RoutePlanner, RouteSettings, follow_polyline,
                                     procedural_allowed, procedural_instruction, route_parts, route_text)
from tests.fixtures.goal_scenes import corridor_grid

F, L, R = FORWARD, LEFT, RIGHT


@pytest.mark.parametrize("actions,text", [
    ([L] * 6 + [F] * 20 + [R] * 6, "turn left, go forward 5 meters, turn right"),
    ([R] * 12 + [F] * 4, "turn around, go forward 1 meter"),
    ([F] * 8 + [L] + [F] * 8, "go forward 4 meters"),  # a lone 15 deg correction is not said
    ([F] * 2 + [L] * 3, "turn left"),  # 0.5 m forward is below navchat's 3-step run
    ([L] * 3 + [F] + [L] * 3 + [F] * 10, "turn left, go forward 2.5 meters"),  # 45 + 45 deg add up to one turn
    ([F, F, R, F, F, L, F, F], "go forward 1.5 meters"),
])
def test_route_text_rules(actions, text):
    assert route_text(route_parts(np.array(actions + [STOP]))) == text


def test_follow_polyline_lattice_headings_and_stop():
    acts = follow_polyline(np.array([[0, 0], [3, 0], [3, 2]]), np.pi / 2)
    assert acts[-1] == STOP and route_text(route_parts(acts)) == "turn right, go forward 3 meters, turn left, go forward 2 meters"


@pytest.mark.parametrize("yaw,first", [(0.0, "go forward 5 meters"), (np.pi, "turn around"), (np.pi / 2, "turn right")])
def test_procedural_from_any_pose_in_an_l_corridor(yaw, first):
    nav, grid = corridor_grid()
    # 0.15 m clearance keeps the route off the corner (the params' 0.1 cuts it: "go forward 4.5 meters")
    text = procedural_instruction(nav, grid, (0.3, 0.5, yaw), (5.5, 4.8),
                                  settings=RouteSettings.from_config(clearance_m=0.15))
    assert text.startswith(first) and text.endswith("turn left, go forward 3 meters")


def test_planner_unreachable_returns_none_and_room_rule():
    nav, grid = corridor_grid()
    planner = RoutePlanner(nav, grid)
    assert procedural_instruction(nav, grid, (0.3, 0.5, 0.0), (-5.0, -5.0), planner=planner) is None
    parts = planner.route((0.3, 0.5, 0.0), planner.goal_mask(np.array([5.5, 4.8]))).parts
    assert procedural_allowed(parts, "hall", "bedroom_1") and not procedural_allowed(parts, "bedroom_1", "bedroom_1")
    assert not procedural_allowed(parts * 2, "hall", "bedroom_1")


def test_a_walk_that_stops_short_of_its_target_finishes_inside_it():
    from pipeline.nav.verify import replay

    nav, grid = corridor_grid()
    xy = grid.cell_to_world(np.argwhere(np.ones(nav.shape, bool))).reshape(*nav.shape, 2)
    target = nav & (xy[..., 0] >= 3.0) & (xy[..., 0] <= 4.0) & (xy[..., 1] <= 1.0)
    start = (0.45, 0.5, 0.0)
    # the polyline ends on the target's first cell (x 3.025); the walk alone stops half a step short of it
    path_end = RoutePlanner(nav, grid).route(start, target, region=True).path.polyline_xy[-1]
    alone = replay(follow_polyline(np.array([start[:2], path_end]), 0.0), start, nav, grid, [], region=target)
    assert not alone.in_region and alone.final_xyyaw[0] == pytest.approx(2.95)
    route = RoutePlanner(nav, grid).route(start, target, region=True)
    res = replay(route.actions, start, nav, grid, [], region=target)
    assert res.in_region and res.collisions == 0 and res.final_xyyaw[0] == pytest.approx(3.2)  # one more step: 2+ cells inside


def test_route_settings_come_from_the_task_params():
    from pipeline.config import TaskParams
    from pipeline.geometry import GridSpec

    p = TaskParams(step_m=0.3, turn_deg=30.0, clearance_m=0.2, stop_radius_m=0.8)
    assert RouteSettings.from_config(p) == RouteSettings(0.3, 30.0, 0.2, 0.8)
    assert RouteSettings.from_config(p, step_m=0.25, stop_radius_m=0.0) == RouteSettings(0.25, 30.0, 0.2, 0.0)
    d = TaskParams()  # the default planner is the params' default (clearance 0.1, not a second default)
    assert RoutePlanner(np.ones((4, 4), bool), GridSpec(4, 4, 0.05, (0.0, 0.2))).settings == RouteSettings(
        d.step_m, d.turn_deg, d.clearance_m, d.stop_radius_m) == RouteSettings.from_config()


def test_a_pose_the_goal_cannot_reach_gets_no_route_and_marches_no_field():
    nav, grid = corridor_grid()
    nav = nav.copy()
    pocket = grid.world_to_cell(np.array([5.5, 4.8]))
    nav[pocket[0] + 30: pocket[0] + 33, :] = False  # a wall across the north arm, 1.5 m south of the goal
    planner = RoutePlanner(nav, grid)
    goal = planner.goal_mask(np.array([5.5, 4.8]))
    assert planner.route((0.3, 0.5, 0.0), goal, key="g") is None
    assert not planner._fields  # neither mask's field was marched: the start's part never reaches the goal
    assert not planner.reach(goal, "clear")[grid.world_to_cell(np.array([0.3, 0.5]))[0]].any()
    # a reachable pose: the same route as a planner that marches first
    route = planner.route((5.5, 4.9, 0.0), goal, key="g")
    fresh = RoutePlanner(nav, grid)
    fresh.field("g", goal, "clear")
    np.testing.assert_array_equal(route.actions, fresh.route((5.5, 4.9, 0.0), goal, key="g").actions)
    np.testing.assert_array_equal(planner.reach(goal, "clear"), np.isfinite(planner.field("g", goal, "clear")))


def test_forget_drops_one_goals_fields_and_keeps_the_others():
    nav, grid = corridor_grid()
    planner = RoutePlanner(nav, grid)
    a, b = planner.goal_mask(np.array([5.5, 4.8])), planner.goal_mask(np.array([1.0, 0.5]))
    for key, mask in (("a", a), (("a", "target"), a), ("b", b), (("stair", "a"), b)):
        planner.route((3.0, 0.5, 0.0), mask, key=key)
    planner.forget("a")
    assert {ck[0] for ck in planner._fields} == {"b", ("stair", "a")}
    assert {ck[0] for ck in planner._goals} == {"b", ("stair", "a")}


def test_goal_cells_eroded_on_their_box_are_the_whole_grids():
    from scipy import ndimage

    from pipeline.nav.actions import DEEP_CELLS
    from pipeline.nav.fmm import target_region

    nav, grid = corridor_grid()
    planner = RoutePlanner(nav, grid)
    for xy, region in (((5.5, 4.8), False), ((0.1, 0.5), True), ((3.0, 0.6), False), ((5.9, 0.1), True)):
        rc = grid.world_to_cell(np.array(xy))
        mask = np.zeros_like(nav)
        mask[max(rc[0] - 6, 0): rc[0] + 6, max(rc[1] - 6, 0): rc[1] + 6] = True
        aim, deep = planner.goal_cells(xy, mask, region=region)
        want = target_region(nav, mask, grid, 0.0 if region else planner.settings.stop_radius_m)
        eroded = ndimage.binary_erosion(want, iterations=DEEP_CELLS)
        np.testing.assert_array_equal(aim, want)
        np.testing.assert_array_equal(deep, eroded if eroded.any() else want)
