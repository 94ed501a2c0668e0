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
