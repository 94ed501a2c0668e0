"""The agents' planner: an agent stranded off the clearance band gets back into it instead of giving up."""

import numpy as np
import pytest

from pipeline.geometry import GridSpec
from pipeline.nav.actions import FORWARD, STOP, RouteSettings
from orion_eval.nav import RECOVER_ACTIONS, NavPlanner
from orion_eval.world import Body, World

GRID = GridSpec(60, 80, 0.05, (0.0, 3.0))
SETTINGS = RouteSettings(step_m=0.25, turn_deg=15.0, clearance_m=0.1, stop_radius_m=0.0)
# two rooms joined by a passage along their top wall; the pose stands 1 cm from the left room's right wall, just
# below the passage's corner: every heading that makes progress toward the passage hits the corner
STRANDED = (1.7399, 2.1921, 0.1222)


def _rooms() -> np.ndarray:
    nav = np.zeros((GRID.rows, GRID.cols), bool)
    nav[5:55, 5:35] = True
    nav[5:55, 45:75] = True
    nav[5:15, 35:45] = True
    return nav


def _cells(rows: slice, cols: slice) -> np.ndarray:
    m = np.zeros((GRID.rows, GRID.cols), bool)
    m[rows, cols] = True
    return m


def _replay(nav: np.ndarray, pose, actions) -> Body:
    world, body = World(nav, GRID, step_m=SETTINGS.step_m, turn_deg=SETTINGS.turn_deg), Body(*pose)
    for a in actions:
        world.act(body, int(a))
    return body


def test_the_plain_planner_finds_no_route_from_the_stranded_pose():
    plain = NavPlanner(_rooms(), GRID, SETTINGS)
    assert plain.route(STRANDED, _cells(slice(28, 32), slice(60, 64)), key="t") is None
    assert not plain.planner.plan_mask[tuple(GRID.world_to_cell(np.array(STRANDED[:2])))]  # off the band


def test_a_stranded_agent_gets_back_into_the_band_and_walks_to_the_target():
    nav, target = _rooms(), _cells(slice(28, 32), slice(60, 64))
    planner = NavPlanner(nav, GRID, SETTINGS, recover=True)
    route = planner.route(STRANDED, target, key="t")
    assert route is not None and route.actions[-1] == STOP
    body = _replay(nav, STRANDED, route.actions)
    assert body.collisions == 0  # every step as planned
    assert target[tuple(GRID.world_to_cell(np.array(body.pose[:2])))]
    # the first step taken ends in the band, within the few actions allowed
    first = int(np.flatnonzero(route.actions == FORWARD)[0]) + 1
    assert first <= RECOVER_ACTIONS
    assert planner.planner.plan_mask[tuple(GRID.world_to_cell(np.array(_replay(nav, STRANDED, route.actions[:first])
                                                                       .pose[:2])))]
    assert np.allclose(route.path.polyline_xy[0], STRANDED[:2])


@pytest.mark.parametrize("pose", [STRANDED, (2.5, 1.5, 0.0)])
def test_a_target_out_of_reach_stays_unreachable(pose):
    nav = _rooms()
    nav[40:50, 76:79] = True  # an island the rooms do not reach
    planner = NavPlanner(nav, GRID, SETTINGS, recover=True)
    assert planner.route(pose, _cells(slice(40, 50), slice(76, 79)), key="island") is None


def test_a_route_from_inside_the_band_is_the_plain_one():
    nav, target = _rooms(), _cells(slice(28, 32), slice(60, 64))
    pose = (1.0, 1.5, 0.3)
    plain = NavPlanner(nav, GRID, SETTINGS).route(pose, target, key="t")
    recovering = NavPlanner(nav, GRID, SETTINGS, recover=True).route(pose, target, key="t")
    assert plain is not None and np.array_equal(plain.actions, recovering.actions)
