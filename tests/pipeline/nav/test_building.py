"""Routes across floors on two made-up floors joined by one straight stair (and a third floor no stair reaches): the
cheapest stair sequence, legs that end at the stair, the climb as forward steps, text that says the stairs, the
geodesic distance through the stair, and an unlinked floor reported instead of an infinite distance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.geometry import GridSpec
from pipeline.nav.actions import FORWARD, LEFT, RIGHT, RoutePlanner, RouteSettings
from pipeline.nav.building import BuildingPlanner, StairLink
from pipeline.nav.region import GoalTargets
from pipeline.nav.verify import replay

CELL = 0.05
GRID = GridSpec(120, 200, CELL, (0.0, 6.0))  # x 0..10 m, y 0..6 m


def floor(walls=()) -> np.ndarray:
    """A 10 m x 6 m room, a 0.5 m border of wall, ``walls`` as (x0, x1, y0, y1) boxes in metres."""
    nav = np.zeros((GRID.rows, GRID.cols), bool)
    nav[10:-10, 10:-10] = True
    for x0, x1, y0, y1 in walls:
        r0, c0 = GRID.world_to_cell(np.array([x0, y1]))
        r1, c1 = GRID.world_to_cell(np.array([x1, y0]))
        nav[max(r0, 0):r1 + 1, max(c0, 0):c1 + 1] = False
    return nav


def disc(xy, radius_m: float) -> np.ndarray:
    rr, cc = np.mgrid[0:GRID.rows, 0:GRID.cols]
    centres = GRID.cell_to_world(np.stack([rr, cc], axis=-1))
    return np.hypot(centres[..., 0] - xy[0], centres[..., 1] - xy[1]) <= radius_m


# the stair climbs 3 m along +x, from (2, 1.5) on the ground floor to (5, 1.5) upstairs; its well is walled off on
# the upper floor (the opening), and on the ground floor the space under it is a wall
STAIR = StairLink("stair_0", 0, 1, (2.0, 1.5), (5.0, 1.5), 3.0)
GROUND = floor(walls=[(2.3, 5.2, 1.0, 2.0)])
UPPER = floor(walls=[(1.8, 4.7, 1.0, 2.0)])


@pytest.fixture(scope="module")
def building() -> BuildingPlanner:
    settings = RouteSettings.from_config()
    planners = {f: RoutePlanner(nav, GRID, settings) for f, nav in ((0, GROUND), (1, UPPER), (2, floor()))}
    return BuildingPlanner(planners, [STAIR])


def targets_at(nav: np.ndarray, xy) -> tuple[GoalTargets, np.ndarray]:
    obj = disc(xy, 0.2)
    region = disc(xy, 1.0) & nav & ~obj
    return GoalTargets.of(region, obj, GRID, stop_radius_m=1.0), obj


def test_a_route_up_walks_to_the_stair_climbs_it_and_ends_in_the_goal_region(building):
    goal_xy = (8.0, 4.5)
    targets, _ = targets_at(UPPER, goal_xy)
    start = (8.0, 1.5, math.pi)
    route = building.route_to_goal(0, start, 1, targets, key="g", face_xy=np.array([goal_xy]))
    assert route is not None and route.floors == [0, 1] and len(route.climbs) == 1
    (f0, leg0), (f1, leg1) = route.legs
    # the first leg ends at the stair's foot, facing up the stair after the climb's turns
    settings = building.planners[0].settings
    end0 = replay(leg0.actions, start, GROUND, GRID, [], step_m=settings.step_m, turn_deg=settings.turn_deg)
    assert math.dist(end0.final_xyyaw[:2], STAIR.foot_xy) <= 0.3 + 1e-9 and end0.collisions == 0
    climb = route.climbs[0]
    turned = (np.sum(climb.actions == LEFT) - np.sum(climb.actions == RIGHT)) * math.radians(settings.turn_deg)
    heading = end0.final_xyyaw[2] + turned
    assert abs(math.remainder(heading, 2 * math.pi)) <= math.radians(settings.turn_deg) / 2 + 1e-9  # along +x
    assert np.sum(climb.actions == FORWARD) == 12  # 3 m of stair in 0.25 m steps
    # the last leg starts at the stair's head and ends inside the goal region
    head = (*STAIR.head_xy, 0.0)
    end1 = replay(leg1.actions, head, UPPER, GRID, [], step_m=settings.step_m, turn_deg=settings.turn_deg,
                  region=targets.region)
    assert end1.in_region and end1.collisions == 0
    # the whole walk: the legs' actions with the climb between, one stop at the end
    acts = route.actions
    assert acts[-1] == 0 and np.count_nonzero(acts == 0) == 1
    assert len(acts) == np.count_nonzero(leg0.actions) + len(climb.actions) + len(leg1.actions)
    assert "; go up the stairs; at the top " in route.text, route.text
    assert route.length_m == pytest.approx(leg0.path.length_m + math.hypot(3.0, 3.0) + leg1.path.length_m)


def test_the_stair_end_is_every_navigable_cell_near_it_the_clearance_band_included(building):
    cells = building.stair_end_cells(STAIR, 0)
    centres = GRID.cell_to_world(np.argwhere(cells))
    assert np.hypot(*(centres - STAIR.foot_xy).T).max() <= 0.3 + 1e-9 and not (cells & ~GROUND).any()
    # the foot is 0.3 m from the wall under the stair: the cells nearest it are in the wall's clearance band
    assert (cells & ~building.planners[0].plan_mask).any()


def test_a_leg_whose_walk_stops_in_the_clearance_band_ends_at_the_stair(building):
    # from here the leg's walk stops on the stair end's cells beside the wall under the stair (0.36 m from the
    # foot when the stair end held only the clearance band's inner cells: the routes stage rejected such episodes)
    start = (2.2, 2.55, 0.0)
    targets, _ = targets_at(UPPER, (8.0, 4.5))
    route = building.route_to_goal(0, start, 1, targets, key="g", face_xy=np.array([(8.0, 4.5)]))
    (_, leg0), _ = route.legs
    settings = building.planners[0].settings
    end = replay(leg0.actions, start, GROUND, GRID, [], step_m=settings.step_m, turn_deg=settings.turn_deg)
    rc = GRID.world_to_cell(np.asarray(end.final_xyyaw[:2]))
    assert end.collisions == 0 and building.stair_end_cells(STAIR, 0)[rc[0], rc[1]]
    assert math.dist(end.final_xyyaw[:2], STAIR.foot_xy) <= 0.3 + 1e-9


def test_the_geodesic_distance_across_floors_goes_through_the_stair(building):
    targets, _ = targets_at(UPPER, (8.0, 4.5))
    goal_field = building.planners[1].field(("g", "region"), targets.region, "navigable", region=True)
    start = (8.0, 1.5)
    dist, seq = building.stair_sequence(0, start, 1, goal_field)
    assert [(lk.id, up) for lk, up in seq] == [("stair_0", True)]
    to_foot = building.stair_end_field(STAIR, 0)[tuple(GRID.world_to_cell(np.array(start)))]
    from_head = goal_field[tuple(GRID.world_to_cell(np.array(STAIR.head_xy)))]
    assert dist == pytest.approx(to_foot + math.hypot(3.0, 3.0) + from_head)
    # about 6 m on the ground floor around the stair's wall, 4.2 m of stair, about 3.5 m upstairs
    assert 12.0 < dist < 16.0


def test_a_route_down_says_so_and_a_same_floor_route_climbs_nothing(building):
    targets, _ = targets_at(GROUND, (8.0, 4.5))
    down = building.route_to_goal(1, (8.0, 1.5, 0.0), 0, targets, key="g0", face_xy=np.array([(8.0, 4.5)]))
    assert down.floors == [1, 0] and not down.climbs[0].up
    assert "go down the stairs; at the bottom " in down.text, down.text
    same = building.route_to_goal(0, (8.0, 1.5, 0.0), 0, targets, key="g0", face_xy=np.array([(8.0, 4.5)]))
    assert same.floors == [0] and not same.climbs and "stairs" not in same.text


def test_a_floor_no_stair_reaches_is_reported_and_its_goals_only_reachable_from_it(building):
    assert building.unlinked() == [2]
    targets, _ = targets_at(floor(), (8.0, 4.5))
    assert building.route_to_goal(0, (8.0, 1.5, 0.0), 2, targets, key="g2", face_xy=np.array([(8.0, 4.5)])) is None
    on_it = building.route_to_goal(2, (2.0, 4.5, 0.0), 2, targets, key="g2", face_xy=np.array([(8.0, 4.5)]))
    assert on_it is not None and on_it.floors == [2]


def test_a_stair_whose_end_is_not_walkable_joins_nothing():
    settings = RouteSettings.from_config()
    blocked = floor(walls=[(4.5, 5.5, 1.0, 2.0)])  # the head lands in a wall upstairs
    b = BuildingPlanner({0: RoutePlanner(GROUND, GRID, settings), 1: RoutePlanner(blocked, GRID, settings)}, [STAIR])
    assert b.unlinked() == [0, 1]
    targets, _ = targets_at(blocked, (8.0, 4.5))
    assert b.route_to_goal(0, (8.0, 1.5, 0.0), 1, targets, key="g", face_xy=np.array([(8.0, 4.5)])) is None
