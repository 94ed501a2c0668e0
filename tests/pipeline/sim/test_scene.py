"""Procedural scenes: determinism, object variety, reachability of every room."""

import numpy as np
import pytest
from scipy import ndimage

from pipeline.config import SimulateParams
from pipeline.errors import ConfigError
from pipeline.paramsfile import parse_params
from pipeline.sim import generate_scene, render_scene_png, scene_seed
from pipeline.sim.topdown import scene_grid
from tests.fixtures.fresh_process import in_fresh_process

NAMES = ["demo", "scene_a", "scene_b"]


@pytest.fixture(scope="module")
def scenes():
    return {n: generate_scene(n, SimulateParams()) for n in NAMES}


def test_same_seed_same_scene_other_name_other_scene(scenes):
    """The same (seed, name) gives the same scene in another process (another string-hash seed); another name or
    seed another scene."""
    again = in_fresh_process("from pipeline.config import SimulateParams\n"
                             "from pipeline.sim import generate_scene, scene_seed",
                             "[generate_scene('demo', SimulateParams()).model_dump(mode='json'), scene_seed(0, 'demo')]")
    assert again == [scenes["demo"].model_dump(mode="json"), scene_seed(0, "demo")]
    assert scenes["scene_a"].model_dump()["objects"] != scenes["demo"].model_dump()["objects"]
    assert generate_scene("demo", SimulateParams(seed=1)).objects != scenes["demo"].objects
    assert len({scene_seed(0, "demo"), scene_seed(0, "demo2"), scene_seed(1, "demo")}) == 3


def test_apartment_scale_rooms_and_classes(scenes):
    for gt in scenes.values():
        x0, x1, y0, y1 = gt.bounds_xy()
        assert 8.0 <= max(x1 - x0, y1 - y0) <= 15.0
        types = [r.type for r in gt.rooms]
        assert {"living room", "kitchen", "bathroom", "bedroom", "office"} <= set(types)
        assert types.count("bedroom") >= 2 and 6 <= len(gt.rooms) <= 7
        assert sorted(o.id for o in gt.objects) == list(range(1, len(gt.objects) + 1))
        classes = {o.cls for o in gt.objects}
        assert len(classes) >= 15, classes
        assert {o.room for o in gt.objects} <= {r.id for r in gt.rooms}
        beds = [o for o in gt.objects if o.cls == "bed"]
        assert len({o.room for o in beds}) >= 2  # one per bedroom
        for cls in classes:
            same = [o for o in gt.objects if o.cls == cls]
            assert len({o.color_name for o in same}) == len(same), cls  # instances told apart by colour
        assert sum(len([o for o in gt.objects if o.cls == c]) > 1 for c in classes) >= 3


def test_objects_inside_their_rooms_and_small_ones_supported(scenes):
    gt = scenes["demo"]
    rooms = {r.id: np.asarray(r.polygon) for r in gt.rooms}
    for o in gt.objects:
        b, p = o.bbox, rooms[o.room]
        assert p[:, 0].min() - 1e-6 <= b.min[0] and b.max[0] <= p[:, 0].max() + 1e-6
        assert p[:, 1].min() - 1e-6 <= b.min[1] and b.max[1] <= p[:, 1].max() + 1e-6
        if o.cls in ("computer", "tv", "microwave"):
            assert b.min[2] > 0.3  # stands on furniture


@pytest.mark.parametrize("name", NAMES)
def test_every_room_reachable_for_robot_radius(scenes, name):
    gt = scenes[name]
    grid = scene_grid(gt, 0.05)
    free = gt.floor_mask(grid) & ~gt.occupancy(grid, 0.05, 1.5)
    navigable = ndimage.distance_transform_edt(free) * 0.05 > 0.18
    labels, _ = ndimage.label(navigable)
    comps = set()
    for room in gt.rooms:
        p = np.asarray(room.polygon)
        centres = grid.cell_to_world(np.stack(np.mgrid[0:grid.rows, 0:grid.cols], axis=-1))
        inside = ((centres[..., 0] > p[:, 0].min()) & (centres[..., 0] < p[:, 0].max())
                  & (centres[..., 1] > p[:, 1].min()) & (centres[..., 1] < p[:, 1].max()))
        ids, counts = np.unique(labels[inside & navigable], return_counts=True)
        assert len(ids), room.id
        comps.add(int(ids[np.argmax(counts)]))
    assert len(comps) == 1  # the main free area of every room is one connected region


def test_room_range_validated():
    with pytest.raises(ConfigError, match="rooms_min must not exceed"):
        parse_params({"scenes": {"s": {"source": "simulate"}}, "simulate": {"rooms_min": 7, "rooms_max": 5}})


def test_topdown_png(scenes, tmp_path):
    import cv2

    path = render_scene_png(scenes["demo"], tmp_path / "plan.png", px_per_m=40)
    img = cv2.imread(str(path))
    x0, x1, y0, y1 = scenes["demo"].bounds_xy()
    assert img.shape[1] == pytest.approx((x1 - x0 + 1.6) * 40, abs=2)
    assert img.shape[0] == pytest.approx((y1 - y0 + 1.6) * 40, abs=2)


def test_every_allowed_room_count_gets_a_layout():
    """simulate.rooms_min/max allow 2..10 rooms; each count yields a living room and a bathroom."""
    import numpy as np

    from pipeline.sim.layout import Rect, assign_types

    for n in range(2, 11):
        types = assign_types(np.random.default_rng(n), [Rect(0.0, 0.0, 1.0 + i, 1.0) for i in range(n)])
        assert len(types) == n and "living room" in types and "bathroom" in types and "" not in types


def test_a_pocket_cut_off_by_furniture_does_not_stop_the_walk():
    from pipeline.sim.trajectory import free_space, plan_actions

    # sim_05 with three rooms: a fridge, a plant, chairs and two cabinets cut the kitchen's far end off its
    # doorway, and the kitchen's most open spot lies in that pocket.
    sp = SimulateParams(frames=160, width=160, height=120, rooms_min=3, rooms_max=3)
    gt = generate_scene("sim_05", sp)
    fs = free_space(gt, sp.robot_radius_m)
    _, n_components = ndimage.label(fs.navigable, structure=np.ones((3, 3)))
    assert n_components > 1
    states, visited = plan_actions(gt, sp.robot_radius_m, 160)
    assert {r.id for r in gt.rooms} <= set(visited) and len(states) > 160
    cells = fs.grid.world_to_cell(states[:, :2])
    assert fs.navigable[cells[:, 0], cells[:, 1]].all()
