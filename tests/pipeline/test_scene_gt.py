"""Ground-truth rasterisation of pipeline.scene_gt: occupancy by cell centres, and the cells a face passes through."""

import json

import numpy as np
import pytest

from pipeline.geometry import GridSpec
from pipeline.errors import ArtifactError
from pipeline.scene_gt import Box, GTFloor, GTObject, GTRoom, GTScene, GTStair


def _scene(parts):
    room = GTRoom(id="room_1", type="bedroom", polygon=[(0, 0), (1, 0), (1, 1), (0, 1)])
    obj = GTObject(id=1, cls="cabinet", room="room_1", parts=parts, color_name="white", color_rgb=(250, 250, 250),
                   material="wood", size="big")
    return GTScene(name="t", seed=0, wall_height_m=2.5, rooms=[room], walls=[], objects=[obj])


def test_a_face_through_cell_centres_marks_them_ambiguous_and_nothing_else():
    grid = GridSpec(10, 10, 0.1, (0.0, 1.0))  # cell centres at x, y = 0.05, 0.15, ..., 0.95
    # x from 0.25 (through centres) to 0.52 (between centres); y from 0.30 to 0.70 (between centres).
    gt = _scene([Box(min=(0.25, 0.30, 0.0), max=(0.52, 0.70, 0.8))])
    occ = gt.occupancy(grid, 0.1, 1.5)
    amb = gt.ambiguous(grid, 0.1, 1.5)
    rows = np.flatnonzero(amb.any(axis=1))
    cols = np.flatnonzero(amb.any(axis=0))
    assert cols.tolist() == [2]  # x = 0.25: the face through the centres of column 2
    assert rows.tolist() == [3, 4, 5, 6]  # y 0.35..0.65, the box's extent
    assert occ[3:7, 3:5].all()  # the unambiguous inside
    # A part outside the height band paints nothing and is never ambiguous.
    low = _scene([Box(min=(0.25, 0.30, 0.0), max=(0.52, 0.70, 0.05))])
    assert not low.occupancy(grid, 0.1, 1.5).any() and not low.ambiguous(grid, 0.1, 1.5).any()


def _two_floors(**change):
    rooms = [GTRoom(id=f"room_{k}", type="bedroom", polygon=[(0, 0), (2, 0), (2, 2), (0, 2)], floor=k) for k in (0, 1)]
    objects = [GTObject(id=k + 1, cls="cabinet", room=f"room_{k}", parts=[Box(min=(0.5, 0.5, z), max=(1, 1, z + 1))],
                        color_name="white", color_rgb=(250, 250, 250), material="wood", size="big", floor=k)
               for k, z in ((0, 0.0), (1, 3.0))]
    floors = [GTFloor(id=0, name="ground floor", floor_z=0.0, ceiling_z=2.8),
              GTFloor(id=1, name="first floor", floor_z=3.0, ceiling_z=5.8)]
    stair = GTStair(id="stairs_0_1", lower=0, upper=1, footprint=[(0, 0), (1, 0), (1, 2), (0, 2)],
                    opening=[(0, 0), (1, 0), (1, 2), (0, 2)], bottom=(0.5, 0.0, 0.0), top=(0.5, 2.0, 3.0),
                    steps=[Box(min=(0, 0, 0), max=(1, 1, 1.5)), Box(min=(0, 1, 0), max=(1, 2, 3.0))])
    walls = [Box(min=(1.9, 0, 0), max=(2, 2, 2.8)), Box(min=(1.9, 0, 3.0), max=(2, 2, 5.8))]
    doc = dict(name="h", seed=1, wall_height_m=2.8, rooms=rooms, walls=walls, objects=objects, floors=floors,
               stairs=[stair])
    return GTScene(**{**doc, **change})


def test_a_single_floor_document_is_written_as_before_floors_existed():
    doc = _scene([Box(min=(0.2, 0.2, 0.0), max=(0.5, 0.5, 0.8))]).model_dump(mode="json")
    assert "floors" not in doc and "stairs" not in doc and "floor" not in doc["rooms"][0]
    assert "floor" not in doc["objects"][0]
    assert GTScene.read(json.loads(json.dumps(doc)), "t") == _scene([Box(min=(0.2, 0.2, 0.0), max=(0.5, 0.5, 0.8))])


def test_a_building_round_trips_and_gives_each_floor_as_a_scene():
    gt = _two_floors()
    doc = json.loads(json.dumps(gt.model_dump(mode="json")))
    assert [r["floor"] for r in doc["rooms"]] == [0, 1] and len(doc["floors"]) == 2 and len(doc["stairs"]) == 1
    assert GTScene.read(doc, "t") == gt
    lower, upper = gt.floor_view(0), gt.floor_view(1)
    assert [r.id for r in lower.rooms] == ["room_0"] and [o.id for o in upper.objects] == [2]
    assert upper.floor_z == 3.0 and upper.wall_height_m == pytest.approx(2.8) and not upper.floors
    assert len(lower.walls) == 3 and len(upper.walls) == 1  # the lower floor's wall and both steps; the upper wall
    grid = GridSpec(20, 20, 0.1, (0.0, 2.0))
    occ_lower, occ_upper = lower.occupancy(grid, 0.1, 1.5), upper.occupancy(grid, 0.1, 1.5)
    step, cabinet = tuple(grid.world_to_cell(np.array([0.25, 0.25]))), tuple(grid.world_to_cell(np.array([0.75, 0.75])))
    assert occ_lower[step] and not occ_upper[step] and occ_lower[cabinet] and occ_upper[cabinet]
    assert occ_upper.sum() == 25 + 20  # the upper cabinet (5 x 5 cells) and the upper wall (a column of 20)
    assert gt.floor_at(1.0) == 0 and gt.floor_at(3.2) == 1 and [f.id for f in gt.all_floors] == [0, 1]
    np.testing.assert_allclose(gt.stairs[0].surface_z(np.array([[0.5, -1.0], [0.5, 1.0], [0.5, 9.0]])), [0, 1.5, 3])
    with pytest.raises(KeyError, match="no floor 2"):
        gt.floor_view(2)
    single = _scene([Box(min=(0.2, 0.2, 0.0), max=(0.5, 0.5, 0.8))])
    assert single.floor_view(0) is single and single.all_floors[0].ceiling_z == 2.5


@pytest.mark.parametrize("change, says", [
    (dict(floors=[GTFloor(id=1, name="a", floor_z=0.0, ceiling_z=2.8)]), "floors: ids must be 0, 1"),
    (dict(floors=[GTFloor(id=0, name="a", floor_z=0.0, ceiling_z=2.8),
                  GTFloor(id=1, name="b", floor_z=2.0, ceiling_z=4.8)]), "floor 1 must lie above floor 0's ceiling"),
    (dict(wall_height_m=2.5), "floor_z / wall_height_m must be floor 0's"),
    (dict(stairs=[]), None),
])
def test_inconsistent_floors_are_refused_naming_what_is_wrong(change, says):
    if says is None:
        assert _two_floors(**change).stairs == []  # a building without stairs is a valid document
        return
    doc = _two_floors().model_dump(mode="json")
    doc.update({k: [v.model_dump(mode="json") for v in val] if isinstance(val, list) else val
                for k, val in change.items()})
    with pytest.raises(ArtifactError, match=says):
        GTScene.read(doc, "frames.zarr: attrs.ground_truth")
    bad_room = _two_floors().model_dump(mode="json")
    bad_room["rooms"][1]["floor"] = 5
    with pytest.raises(ArtifactError, match=r"rooms \['room_1'\]: floor is not one of the 2 floors"):
        GTScene.read(bad_room, "t")
