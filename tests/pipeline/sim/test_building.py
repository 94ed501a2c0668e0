"""Simulated buildings: a house's floors and stairs (geometry, connectivity, rendered depth of the steps and of the
slab with its opening, a walk up and down), and a large office floor."""

import numpy as np
import pytest

from pipeline.config import BuildingParams, SimulateParams
from pipeline.geometry import Intrinsics
from pipeline.sim import SceneRaycaster, SimulatedRecording, floor_truths, free_space, generate_scene
from pipeline.sim.building import MAX_RISE_M, SLAB_M, TREAD_M, notched_polygon, rect_minus
from pipeline.sim.layout import Rect
from pipeline.sim.simulate import frame_floors
from pipeline.sim.topdown import scene_grid
from pipeline.sim.trajectory import STAIR_SPOT_M
from scipy import ndimage

HOUSE = BuildingParams(kind="house", stories=2)


@pytest.fixture(scope="module")
def house():
    return generate_scene("house_t", SimulateParams(), HOUSE)


def _way(stair) -> np.ndarray:
    d = np.subtract(stair.top[:2], stair.bottom[:2])
    return d / np.hypot(*d)


def test_house_floors_rooms_and_objects(house):
    f0, f1 = house.floors
    assert (f0.id, f0.name, f1.id, f1.name) == (0, "ground floor", 1, "first floor")
    assert f0.floor_z == house.floor_z == 0.0 and f0.ceiling_z == pytest.approx(house.wall_height_m)
    assert f1.floor_z == pytest.approx(f0.ceiling_z + SLAB_M) and f1.ceiling_z - f1.floor_z == pytest.approx(
        house.wall_height_m)
    assert len({r.id for r in house.rooms}) == len(house.rooms)
    for f in house.floors:
        rooms = [r for r in house.rooms if r.floor == f.id]
        assert len(rooms) >= 4 and sum(r.type == "hallway" for r in rooms) == 1  # 3-4 rooms and the stair hall
        objects = [o for o in house.objects if o.floor == f.id]
        assert len(objects) >= 10 and {o.room for o in objects} <= {r.id for r in rooms}
        for o in objects:  # every part stands on its own floor, under its ceiling
            assert min(p.min[2] for p in o.parts) >= f.floor_z - 1e-6 and max(p.max[2] for p in o.parts) <= f.ceiling_z
    assert {r.type for r in house.rooms if r.floor == 0} >= {"living room", "kitchen", "bathroom"}
    assert sorted(o.id for o in house.objects) == list(range(1, len(house.objects) + 1))


def test_house_stairs_join_the_floors(house):
    (stair,) = house.stairs
    assert (stair.id, stair.lower, stair.upper) == ("stairs_0_1", 0, 1)
    assert stair.bottom[2] == house.floors[0].floor_z and stair.top[2] == pytest.approx(house.floors[1].floor_z)
    tops = [s.max[2] for s in stair.steps]
    risers = np.diff([0.0, *tops, house.floors[1].floor_z])
    assert np.all(risers > 0.1) and np.all(risers <= MAX_RISE_M + 1e-6)  # a climb a Habitat agent can take
    assert np.hypot(*np.subtract(stair.top[:2], stair.bottom[:2])) == pytest.approx(len(stair.steps) * TREAD_M)
    # the opening is cut out of the upper floor and nowhere else; the flight stands on the lower floor
    grid = scene_grid(house, 0.05)
    opening = np.mean(stair.opening, axis=0)
    rc = tuple(grid.world_to_cell(opening))
    assert not house.floor_view(1).floor_mask(grid)[rc] and house.floor_view(0).floor_mask(grid)[rc]
    lower, upper = floor_truths(house, grid, 0.1, 1.5)
    assert lower.occupied[rc] and not upper.occupied[rc] and lower.stairs[rc] and upper.stairs[rc]
    # where the robot takes the stairs is open floor joined to every room of its floor
    way = _way(stair)
    for floor, spot in ((0, np.asarray(stair.bottom[:2]) - STAIR_SPOT_M * way),
                        (1, np.asarray(stair.top[:2]) + STAIR_SPOT_M * way)):
        fs = free_space(house.floor_view(floor), 0.18)
        labels, _ = ndimage.label(fs.navigable)
        here = labels[tuple(fs.grid.world_to_cell(spot))]
        assert here > 0
        for k, room in enumerate(house.floor_view(floor).rooms):
            assert (labels[fs.room_of_cell == k] == here).any(), room.id
    # railings keep the robot out of the opening on the upper floor, except at the flight's top
    fs1 = free_space(house.floor_view(1), 0.18)
    assert not fs1.is_navigable(np.asarray(stair.opening)).any()


def test_rendered_depth_of_steps_and_the_slab_opening(house):
    (stair,) = house.stairs
    r = SceneRaycaster(house, Intrinsics.from_hfov(64, 48, 90.0))
    way = _way(stair)
    spot = np.asarray(stair.bottom[:2]) - STAIR_SPOT_M * way
    rise = stair.steps[0].max[2]
    # horizontal rays toward the flight from 0.5 m before it: at height z they meet riser ceil(z / rise)
    heights = np.array([0.5, 1.5, 2.5, 4.5]) * rise
    rays = np.array([[*spot, z, *way, 0.0] for z in heights], np.float32)
    t = r.cast(rays)["t_hit"]
    np.testing.assert_allclose(t, STAIR_SPOT_M + np.floor(heights / rise) * TREAD_M, atol=1e-4)
    # straight up from the lower floor: the ceiling beside the flight, the upper floor's ceiling through the opening
    f0, f1 = house.floors
    beside = spot - 0.3 * way
    inside = np.mean(stair.opening, axis=0)
    up = np.array([[*beside, 1.0, 0, 0, 1], [*inside, stair.steps[-1].max[2] + 0.1, 0, 0, 1]], np.float32)
    t = r.cast(up)["t_hit"]
    np.testing.assert_allclose(t, [f0.ceiling_z - 1.0, f1.ceiling_z - stair.steps[-1].max[2] - 0.1], atol=1e-4)
    # down from the upper floor: its own surface beside the opening, a step's tread through it
    top_spot = np.asarray(stair.top[:2]) + STAIR_SPOT_M * way
    down = np.array([[*top_spot, f1.floor_z + 1.0, 0, 0, -1], [*inside, f1.floor_z + 1.0, 0, 0, -1]], np.float32)
    t = r.cast(down)["t_hit"]
    tread = max(s.max[2] for s in stair.steps if s.min[0] <= inside[0] <= s.max[0] and s.min[1] <= inside[1] <= s.max[1])
    np.testing.assert_allclose(t, [1.0, f1.floor_z + 1.0 - tread], atol=1e-4)
    # a whole frame from the foot of the stairs sees the steps: valid depth everywhere, nothing beyond the hall
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = (way[1], -way[0], 0.0), (0.0, 0.0, -1.0), (way[0], way[1], 0.0)
    T[:3, 3] = (*spot, 0.88)
    out = r.raycast(T[None])
    assert np.isfinite(out.depth_m).all() and out.depth_m.max() < 12.0


@pytest.fixture(scope="module")
def walk():
    return SimulatedRecording("house_t", SimulateParams(frames=60, width=48, height=36), building=HOUSE)


def test_the_walk_climbs_tours_both_floors_and_comes_down(walk, house):
    gt = walk.gt
    assert gt == house
    s = walk.states
    assert set(walk.visited) == {r.id for r in gt.rooms}
    moves = np.hypot(*np.diff(s[:, :2], axis=0).T)
    turns = np.abs(np.diff(s[:, 2]))
    assert ((moves > 0) != (turns > 0)).all() and moves.max() <= 0.25 + 1e-9
    (stair,) = gt.stairs
    z = s[:, 3]
    on_floor = np.isin(np.round(z, 6), [round(f.floor_z, 6) for f in gt.floors])
    np.testing.assert_allclose(z[~on_floor], stair.surface_z(s[~on_floor, :2]))  # on the flight: its surface
    assert z[0] == z[-1] == 0.0 and z.max() == pytest.approx(gt.floors[1].floor_z)  # up, and back down
    ups = np.flatnonzero(np.diff((z > 1.0).astype(int)) != 0)
    assert len(ups) == 2  # one climb, one descent
    lo, hi = np.min(stair.footprint, axis=0), np.max(stair.footprint, axis=0)
    gap = np.hypot(*np.maximum(np.maximum(lo - s[:, :2], s[:, :2] - hi), 0.0).T)
    for f in gt.floors:  # on a floor, the robot is in that floor's free space, or stepping on or off the stairs
        here = (np.abs(z - f.floor_z) < 1e-9) & (gap > STAIR_SPOT_M)
        assert free_space(gt.floor_view(f.id), 0.1).is_navigable(s[here, :2]).all()
    # frames: the camera rides 0.88 m above the surface under it, and frames are taken on both floors
    floors = frame_floors(gt, walk.frame_T, 0.88)
    assert set(floors.tolist()) == {0, 1} and (floors == 1).sum() >= 10
    key_z = np.interp(walk.frame_ns, np.linspace(walk.frame_ns[0], walk.frame_ns[-1], len(s)), z)
    np.testing.assert_allclose(walk.frame_T[:, 2, 3], key_z + 0.88, atol=1e-4)  # key stamps are whole ns


@pytest.mark.parametrize("frames", [60, 240])
def test_the_walk_enters_each_hall_end_and_splits_its_actions_by_floor_area(house, frames):
    """Each floor's stair hall has a dead end beyond the flight (downstairs past its head, upstairs past the railing
    at its foot) that no doorway leads through: the walk goes to its far wall on every floor, and each floor gets
    a share of the actions as large as its share of the navigable area (an apartment's tour per floor)."""
    p = SimulateParams(frames=frames)
    walk = SimulatedRecording("house_t", p, gt=house)
    s = walk.states
    (stair,) = house.stairs
    way = _way(stair)
    axis = int(np.argmax(np.abs(way)))
    foot, head = np.dot(stair.bottom[:2], way), np.dot(stair.top[:2], way)
    along = s[:, :2] @ way
    areas = []
    for f in house.floors:
        on = s[:, 3] == f.floor_z
        (hall,) = [r for r in house.rooms if r.floor == f.id and r.type == "hallway"]
        ends = np.sort(np.asarray(hall.polygon)[:, axis]) * np.sign(way[axis])
        if f.id == stair.lower:  # past the flight's head, up to the wall at the hall's far end
            wall, reached = max(ends), along[on].max()
            assert reached > head + 1.0
        else:  # past the railing at the flight's foot
            wall, reached = min(ends), along[on].min()
            assert reached < foot - 1.0
        assert abs(wall - reached) < 1.0, (f.id, wall, reached)  # the dead end is at least LANDING_M (2 m) long
        areas.append(free_space(house.floor_view(f.id), p.robot_radius_m).navigable.sum())
        assert on.sum() >= p.min_actions_per_frame * frames * areas[-1] / sum(
            free_space(house.floor_view(g.id), p.robot_radius_m).navigable.sum() for g in house.floors)


@pytest.mark.parametrize("frames", [240, 480])
def test_each_floor_is_toured_in_whole_rounds(house, frames):
    """A floor's tour never stops mid-round, as an apartment's does not: every room of a floor is looked from as
    many viewpoints as the others (a room with fewer viewpoints has them all; the stair hall one more, its dead
    end), so no room is left seen from one spot while its neighbours got two."""
    from collections import Counter

    from pipeline.sim.trajectory import _FloorTour

    walk = SimulatedRecording("house_t", SimulateParams(frames=frames), gt=house)
    seen = Counter(walk.visited)
    for f in house.floors:
        tour = _FloorTour(house.floor_view(f.id), SimulateParams().robot_radius_m)
        rooms = tour.gt.rooms
        hall = [r.type == "hallway" for r in rooms]
        rounds = max(seen[r.id] - h for r, h in zip(rooms, hall))
        assert rounds >= 1
        for r, h, views in zip(rooms, hall, tour.views):
            assert seen[r.id] == min(rounds + h, len(views)), (f.id, r.id, seen[r.id], rounds)


def test_three_stories_switch_back():
    gt = generate_scene("house_t", SimulateParams(), BuildingParams(kind="house", stories=3))
    assert [f.id for f in gt.floors] == [0, 1, 2] and [(s.lower, s.upper) for s in gt.stairs] == [(0, 1), (1, 2)]
    a, b = (_way(s) for s in gt.stairs)
    np.testing.assert_allclose(a, -b)  # the second flight climbs back over the first
    np.testing.assert_allclose(gt.stairs[1].bottom[:2], np.add(gt.stairs[0].top[:2], (1.0 * np.abs(a[::-1]))))
    states = SimulatedRecording("house_t", SimulateParams(frames=40), building=BuildingParams(
        kind="house", stories=3)).states
    assert np.isclose(states[:, 3], gt.floors[2].floor_z).any() and states[-1, 3] == 0.0


def test_office_floor_extent_and_connectivity():
    gt = generate_scene("office_t", SimulateParams(), BuildingParams(kind="office"))
    x0, x1, y0, y1 = gt.bounds_xy()
    assert (x1 - x0, y1 - y0) == (60.0, 40.0) and not gt.floors and not gt.stairs
    assert len(gt.rooms) == round(60 * 40 / 90) and {r.type for r in gt.rooms} >= {"open office", "meeting room"}
    fs = free_space(gt, 0.18)
    assert fs.grid.cell_size_m == 0.1  # a floor this large is planned on 10 cm cells
    labels, _ = ndimage.label(fs.navigable)
    biggest = np.bincount(labels[labels > 0]).argmax()
    for k in range(len(gt.rooms)):
        assert (labels[fs.room_of_cell == k] == biggest).any(), gt.rooms[k].id
    assert len(gt.objects) > 200


def test_small_office_walk_visits_every_room():
    rec = SimulatedRecording("office_t", SimulateParams(frames=40), building=BuildingParams(
        kind="office", size_m=(24.0, 16.0), room_area_m2=60.0))
    assert set(rec.visited) == {r.id for r in rec.gt.rooms} and np.all(rec.states[:, 3] == 0.0)


def test_rect_helpers():
    r = Rect(0.0, 0.0, 4.0, 2.0)
    pieces = rect_minus(r, Rect(-1.0, 0.5, 1.0, 1.5))
    assert sum(p.area for p in pieces) == pytest.approx(8.0 - 1.0)
    poly = np.asarray(notched_polygon(Rect(0.0, 0.0, 2.0, 10.0), Rect(-0.1, 3.0, 1.0, 7.0)))
    area = 0.5 * np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    assert area == pytest.approx(20.0 - 4.0) and len(poly) == 8  # counter-clockwise, notch cut out
    with pytest.raises(ValueError, match="must reach a side"):
        notched_polygon(Rect(0.0, 0.0, 2.0, 10.0), Rect(0.5, 3.0, 1.0, 7.0))
