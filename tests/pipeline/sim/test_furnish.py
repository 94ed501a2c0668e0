"""Furnishing: every apartment holds several instances of the goal classes the task is hard on."""

from collections import Counter

import pytest

from pipeline.config import SimulateParams
from pipeline.sim import generate_scene
from pipeline.sim.furnish import MIN_INSTANCES

SCENES = [f"sim_{i:02d}" for i in range(10)]


@pytest.mark.parametrize("seed", [0, 2])
def test_every_scene_has_three_goal_classes_with_three_or_more_instances(seed):
    for name in SCENES:  # seed 2's sim_07 had one picture class only before the top-up
        gt = generate_scene(name, SimulateParams(seed=seed))
        counts = Counter(o.cls for o in gt.objects)
        assert all(counts[cls] >= n for cls, n in MIN_INSTANCES.items()), (seed, name, counts)
        assert sum(n >= 3 for n in counts.values()) >= len(MIN_INSTANCES) == 3
        for cls in MIN_INSTANCES:  # distinct colours: each instance is its own goal, not one same_goal group
            same = [o for o in gt.objects if o.cls == cls]
            assert len({o.color_name for o in same}) == len(same)


def test_a_three_room_apartment_is_topped_up_too():
    for name in ("a", "b", "c", "d"):
        gt = generate_scene(name, SimulateParams(rooms_min=3, rooms_max=3))
        counts = Counter(o.cls for o in gt.objects)
        assert len(gt.rooms) == 3
        assert all(counts[cls] >= n for cls, n in MIN_INSTANCES.items()), (name, counts)
        assert sorted(o.id for o in gt.objects) == list(range(1, len(gt.objects) + 1))
