"""Ground-truth rasterisation of pipeline.scene_gt: occupancy by cell centres, and the cells a face passes through."""

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.scene_gt import Box, GTObject, GTRoom, GTScene


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
