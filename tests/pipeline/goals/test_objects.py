import numpy as np
import pytest

from pipeline.errors import InputDataError
from pipeline.goals.objects import objects_from_file, objects_from_gt, polygon_area, rasterize_polygons
from pipeline.scene_gt import Box, GTObject
from tests.fixtures.goal_scenes import house_grid, house_scene


def test_objects_from_gt_keys_footprints_and_heights():
    gt = house_scene()
    # an L-shaped desk of two parts: its footprint is the union outline, not the bounding box
    desk = GTObject(id=12, cls="desk", room="living room_1", color_name="white", color_rgb=(250, 250, 250),
                    material="wood", size="big",
                    parts=[Box(min=(3.0, 4.5, 0), max=(4.0, 5.0, 0.75)), Box(min=(3.5, 5.0, 0), max=(4.0, 5.5, 0.75))])
    objs = objects_from_gt(gt.model_copy(update={"objects": gt.objects + [desk]})).by_key()
    assert [k for k in objs if k.startswith("chair")] == ["chair_0", "chair_1", "chair_2", "chair_3"]
    assert objs["chair_0"].instance_id == 3 and objs["lamp_0"].z_range == (0.6, 1.0)
    assert polygon_area(np.asarray(objs["desk_0"].footprint)) == pytest.approx(0.75, abs=0.02)
    assert polygon_area(np.asarray(objs["bed_0"].footprint)) == pytest.approx(1.7 * 1.7, abs=1e-6)
    np.testing.assert_allclose(objs["bed_0"].mass_center, (7.05, 5.05))
    grid = house_grid()
    ras = rasterize_polygons([np.asarray(objs["bed_0"].footprint)], grid)
    assert ras.sum() == pytest.approx(1.7 * 1.7 / grid.cell_size_m**2, rel=0.05)


def test_user_file_objects_and_field_errors(tmp_path):
    good = tmp_path / "objects.yaml"
    good.write_text("rooms: [{id: office_1, type: office}]\nobjects:\n"
                    "- {key: desk_0, cls: desk, instance_id: 0, room: office_1,\n"
                    "   footprint: [[0, 0], [1, 0], [1, 1], [0, 1]], mass_center: [0.5, 0.5]}\n")
    objs = objects_from_file(good, "s")
    assert objs.source == "file" and objs.objects[0].size == "big"
    bad = tmp_path / "bad.yaml"
    bad.write_text(good.read_text().replace("[[0, 0], [1, 0], [1, 1], [0, 1]]", "[[0, 0], [1, 0]]"))
    with pytest.raises(InputDataError, match=r"bad.yaml; field objects\[0\].footprint: .*at least 3 items"):
        objects_from_file(bad, "s")
    bad.write_text(good.read_text().replace("room: office_1,", "room: kitchen_1,"))
    with pytest.raises(InputDataError, match=r"field objects\[0\].room: room 'kitchen_1' is not one of"):
        objects_from_file(bad, "s")
