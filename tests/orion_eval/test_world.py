"""The agent's body, collisions and the success rule on a hand-made grid (2.5-D line of sight)."""

import math

import numpy as np

from orion_eval.world import Body, SuccessRule, World
from pipeline.geometry import GridSpec
from pipeline.nav.actions import FORWARD, LEFT, RIGHT

GRID = GridSpec(rows=100, cols=100, cell_size_m=0.05, origin_xy=(0.0, 5.0))  # x 0..5, y 0..5


def test_actions_and_collisions():
    nav = np.ones((100, 100), bool)
    nav[:, 60:] = False  # blocked east of x = 3
    w = World(nav, GRID)
    b = Body(2.5, 2.5, 0.0)
    assert w.act(b, FORWARD) and math.isclose(b.x, 2.75)
    assert not w.act(b, FORWARD) and b.collisions == 1 and math.isclose(b.x, 2.75)  # would cross x = 3
    w.act(b, LEFT)
    assert math.isclose(b.yaw, math.radians(15))
    w.act(b, RIGHT), w.act(b, RIGHT)
    assert math.isclose(b.yaw, math.radians(-15)) and b.steps == 5 and b.travelled_m == 0.25
    assert b.actions == [FORWARD, FORWARD, LEFT, RIGHT, RIGHT]


def _goal(rule, height):
    # a 0.4 x 0.4 m box (0.8 m tall) centred at (4.0, 2.5)
    fp = np.array([(3.8, 2.3), (4.2, 2.3), (4.2, 2.7), (3.8, 2.7)])
    mask = np.zeros((100, 100), bool)
    mask[46:54, 76:84] = True
    return rule.geometry([fp], [(4.0, 2.5)], [(0.0, 0.8)], mask)


def test_paper_rule_distance_view_and_sight():
    height = np.zeros((100, 100), np.float32)
    rule = SuccessRule(GRID, height, 0.88, rule="paper", distance_m=1.5, hfov_deg=90)
    g = _goal(rule, height)
    assert rule.evaluate((2.5, 2.5, 0.0), g)["success"]  # 1.3 m from the footprint, facing it
    r = rule.evaluate((2.2, 2.5, 0.0), g)
    assert not r["success"] and r["distance_m"] == 1.6
    assert not rule.evaluate((2.5, 2.5, math.radians(50)), g)["success"]  # centre 50 deg off the axis
    assert rule.evaluate((2.5, 2.5, math.radians(40)), g)["success"]
    height[:, 60:62] = 2.0  # a wall between agent and goal
    walled = SuccessRule(GRID, height, 0.88, rule="paper")
    assert not walled.evaluate((2.5, 2.5, 0.0), _goal(walled, height))["visible"]
    height[:, 60:62] = 0.6  # a low table: the goal's top is still in sight
    low = SuccessRule(GRID, height, 0.88, rule="paper")
    assert low.evaluate((2.5, 2.5, 0.0), _goal(low, height))["success"]


def test_navchat_bands_are_tighter():
    height = np.zeros((100, 100), np.float32)
    rule = SuccessRule(GRID, height, 0.88, rule="navchat")
    g = _goal(rule, height)
    assert rule.evaluate((2.5, 2.5, 0.0), g)["success"]  # 1.3 m, 0 deg: the (1.4 m, 15 deg) band
    assert not rule.evaluate((2.5, 2.5, math.radians(20)), g)["success"]  # 1.3 m, 20 deg: paper yes, navchat no
    assert SuccessRule(GRID, height, 0.88).evaluate((2.5, 2.5, math.radians(20)), g)["success"]
    assert rule.evaluate((2.7, 2.5, 0.0), g)["success"]  # 1.1 m, 0 deg
    assert not rule.evaluate((2.7, 2.5, math.radians(35)), g)["success"]
    assert rule.evaluate((3.3, 2.5, math.radians(40)), g)["success"]  # 0.5 m, 40 deg


def _two_floors():
    """Two floors of the 5 m x 5 m grid joined by a straight stair along y = 1 from x = 1 (foot, floor 0) to x = 3
    (head, floor 1), rising 2.5 m; the flight's cells are walls on floor 0, the stairwell is off floor 1's grid."""
    from orion_eval.world import Stairway
    from pipeline.nav.building import StairLink

    nav0 = np.ones((100, 100), bool)
    nav0[75:85, 22:60] = False  # the flight seen from floor 0: x 1.1 .. 3.0, y 0.75 .. 1.25
    nav1 = np.ones((100, 100), bool)
    nav1[75:85, 20:58] = False  # the stairwell on floor 1: x 1.0 .. 2.9
    link = StairLink("stairs_0", 0, 1, (1.0, 1.0), (3.0, 1.0), 2.5)
    ends = {}
    for f, (x, y) in ((0, link.foot_xy), (1, link.head_xy)):
        rr, cc = np.mgrid[0:100, 0:100]
        xy = GRID.cell_to_world(np.stack([rr.ravel(), cc.ravel()], axis=1))
        ends[f] = (np.hypot(xy[:, 0] - x, xy[:, 1] - y) <= 0.3).reshape(100, 100) & (nav0 if f == 0 else nav1)
    way = Stairway(link, ends, GRID, 0.25)
    return World(nav0, GRID, floors={1: (nav1, GRID)}, stairs=[way]), way


def test_forward_steps_along_a_stair_climb_to_the_next_floor_and_back():
    """As a Habitat agent climbs: MoveForward on the stair from its foot, facing along it, reaches the head on the
    upper floor after ceil(run / step) steps, the distance travelled being the stair's length along its slope."""
    w, way = _two_floors()
    assert way.steps == 8
    b = Body(0.9, 1.0, 0.0)
    assert w.act(b, FORWARD) and b.floor == 0 and b.stair == (0, 1) and math.isclose(b.x, 1.25)
    for _ in range(7):
        assert w.act(b, FORWARD)
    assert b.floor == 1 and b.stair is None and (b.x, b.y) == (3.0, 1.0) and b.collisions == 0
    assert math.isclose(b.travelled_m, way.link.length_m) and b.pose.floor == 1 and b.floors[-1] == 1
    assert w.act(b, FORWARD) and b.floor == 1 and math.isclose(b.x, 3.25)  # on along floor 1
    for _ in range(12):  # turn around (180 deg)
        w.act(b, LEFT)
    # within reach of the head, facing into the stairwell: the next step is the stair's top step
    assert w.act(b, FORWARD) and math.isclose(b.x, 2.75) and b.floor == 1 and b.stair == (0, 7)
    for _ in range(7):  # down: 8 steps from the head to the foot
        assert w.act(b, FORWARD)
    assert b.floor == 0 and (b.x, b.y) == (1.0, 1.0) and b.floors[-1] == 0 and b.stair is None


def test_a_stair_is_entered_only_from_its_end_facing_along_it_and_its_sides_collide():
    w, _ = _two_floors()
    b = Body(0.9, 1.0, math.radians(45))  # at the foot, facing off the stair's line: a floor step
    assert w.act(b, FORWARD) and b.stair is None and b.floor == 0
    b = Body(0.9, 1.0, 0.0)
    w.act(b, FORWARD), w.act(b, FORWARD)
    w.act(b, LEFT), w.act(b, LEFT), w.act(b, LEFT)  # 45 deg across the flight
    assert not w.act(b, FORWARD) and b.collisions == 1 and b.stair == (0, 2) and b.floor == 0
    b = Body(2.0, 3.0, -math.pi / 2)  # far from both ends: the floor's walls as ever
    assert w.act(b, FORWARD) and b.stair is None


def test_a_single_floor_world_has_no_stairs_and_its_poses_are_floor_0():
    w = World(np.ones((100, 100), bool), GRID)
    b = Body(1.0, 1.0, 0.0)
    w.act(b, FORWARD)
    assert w.stairs == [] and b.pose == (1.25, 1.0, 0.0) and b.pose.floor == 0 and b.floors == [0]
