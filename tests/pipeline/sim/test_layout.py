"""Floor plans: doorways fit the wall two rooms share."""

import numpy as np

from pipeline.config import SimulateParams
from pipeline.sim import generate_scene
from pipeline.sim.layout import Rect, _place_doors


def test_a_doorway_on_a_barely_wide_enough_wall_keeps_its_quarter_metre_either_side():
    """A 1.409 m shared wall leaves 0.909 m for the doorway: rounded to the centimetre that was 0.91, which did not
    fit between the 0.25 m kept either side (numpy: "high - low < 0"); the doorway now narrows to 0.90."""
    leaves = [Rect(0.0, 0.0, 5.0, 1.409), Rect(5.0, 0.0, 10.0, 1.409)]
    splits = [(0, 5.0, 0.0, 1.409, "s")]
    for seed in range(20):
        (door,) = _place_doors(np.random.default_rng(seed), leaves, ["sa", "sb"], splits)
        # its start is said to the centimetre too: the quarter metre kept either side, to within half of one
        assert door.lo >= 0.25 - 0.005 and door.hi <= 1.409 - 0.25 + 0.005
        assert door.hi - door.lo >= 0.9 - 1e-9


def test_the_fresh_ten_room_plan_that_failed_on_it_builds():
    """The scene of a fresh ten-room set (simulate.seed 48271, unseen_hm_06) whose plan had such a wall."""
    params = SimulateParams(seed=48271, rooms_min=10, rooms_max=10)
    gt = generate_scene("unseen_hm_06", params)
    assert len(gt.rooms) == 10
