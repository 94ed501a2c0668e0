"""The goals stage's floor helpers: a floor's footprint raster indexes the scene's objects, objects on a floor the
reconstruction lacks are refused by name, and a start pose on a cell never seen as floor moves to the nearest
navigable cell (within a metre) or stays."""

import numpy as np
import pytest

from pipeline.errors import InputDataError
from pipeline.geometry import GridSpec
from pipeline.goals.floors import floor_object_index, floors_of_objects, walkable_start
from pipeline.goals.objects import ObjectRecord, ObjectSet

GRID = GridSpec(40, 60, 0.05, (0.0, 2.0))  # x 0..3 m, y 0..2 m


def _obj(key, x0, floor):
    return ObjectRecord(key=key, cls="table", instance_id=1, footprint=[(x0, 0.5), (x0 + 0.5, 0.5), (x0 + 0.5, 1.0)],
                        mass_center=(x0 + 0.33, 0.67), floor=floor)


def test_a_floors_raster_holds_its_objects_by_their_scene_wide_index():
    objset = ObjectSet(scene="s", objects=[_obj("a", 0.5, 0), _obj("b", 0.5, 1), _obj("c", 2.0, 1)])
    lower, upper = floor_object_index(objset, 0, GRID), floor_object_index(objset, 1, GRID)
    assert set(np.unique(lower)) == {0, 1} and set(np.unique(upper)) == {0, 2, 3}
    assert ((lower == 1) == (upper == 2)).all()  # same footprint, each on its own floor
    assert not floor_object_index(objset, 2, GRID).any()


def test_objects_on_a_floor_the_reconstruction_lacks_are_named():
    objset = ObjectSet(scene="s", objects=[_obj("a", 0.5, 0), _obj("b", 0.5, 2)])
    with pytest.raises(InputDataError, match=r"\['b'\] lie on floors the reconstruction does not have \(it found 2\)"):
        floors_of_objects(objset, 2, "objects.yaml")
    floors_of_objects(objset, 3, "objects.yaml")


def test_a_start_on_an_unseen_cell_moves_to_the_nearest_navigable_cell_within_a_metre():
    nav = np.zeros((GRID.rows, GRID.cols), bool)
    nav[:, 30:] = True  # x >= 1.5 m
    pose, moved = walkable_start((1.1, 1.0, 0.7), nav, GRID)
    assert pose[2] == 0.7 and moved == pytest.approx(0.425, abs=0.03) and nav[tuple(GRID.world_to_cell(np.array(pose[:2])))]
    assert walkable_start((0.2, 1.0, 0.7), nav, GRID) == ((0.2, 1.0, 0.7), 0.0)  # 1.3 m away: stays
    assert walkable_start((2.0, 1.0, 0.7), nav, GRID) == ((2.0, 1.0, 0.7), 0.0)  # already navigable
    assert walkable_start(None, nav, GRID) == (None, 0.0)


def test_the_start_may_move_as_far_as_the_first_camera_is_blind_to_the_floor():
    """A camera 1.25 m up looking level, 240 rows at fy 160 (a 74 degree vertical field), first sees the floor
    1.25 / tan(36.9 deg) = 1.67 m ahead: an office's start 1.3 m from the nearest seen floor moves with that bound
    (it stayed with the old fixed metre, and the office's goals had no procedural feedback)."""
    from pipeline.geometry import Intrinsics, camera_pose_from_base
    from pipeline.goals.floors import blind_radius_m

    intr = Intrinsics(160.0, 160.0, 160.0, 120.0, 320, 240)
    level = camera_pose_from_base(0.4, 1.0, 0.3, 1.25)
    assert blind_radius_m(level, intr, 0.0) == pytest.approx(1.25 / 0.75, rel=1e-6)
    assert blind_radius_m(level, intr, 3.0) == float("inf")  # under the floor named: no sight of it
    up = level.copy()
    up[:3, :3] = up[:3, :3] @ np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1.0]])  # upside down: the bottom row looks up
    assert blind_radius_m(up, intr, 0.0) == float("inf")
    nav = np.zeros((GRID.rows, GRID.cols), bool)
    nav[:, 30:] = True
    pose, moved = walkable_start((0.2, 1.0, 0.7), nav, GRID, max_m=blind_radius_m(level, intr, 0.0))
    assert moved == pytest.approx(1.325, abs=0.03) and nav[tuple(GRID.world_to_cell(np.array(pose[:2])))]
