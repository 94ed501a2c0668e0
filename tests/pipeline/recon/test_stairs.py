"""Stairs and ramps between floors (pipeline.recon.stairs): a rendered two-storey house end to end, and ramps,
tables and stair-less buildings on synthetic surfaces."""

import numpy as np
import pytest

from pipeline.config import ReconstructParams
from pipeline.geometry import GridSpec
from pipeline.recon.stairs import Flight, find_stairs, unlinked_warnings
from pipeline.recon.surface import Surface
from pipeline.recon.store import Floor
from tests.fixtures.recon_scenes import STOREY_M


def test_a_two_storey_house_is_two_floors_joined_by_its_stairs(house):
    summary, recon, gt = house
    assert [f.floor_z_m for f in recon.floors] == pytest.approx([0.0, STOREY_M], abs=0.02)
    assert recon.floors[0].ceiling_z_m == pytest.approx(STOREY_M - 0.2, abs=0.02)  # the slab's underside
    assert "warnings" not in summary
    (stairs,) = recon.stairs
    assert stairs.kind == "stairs" and (stairs.bottom.floor, stairs.top.floor) == (0, 1)
    assert stairs.rise_m == pytest.approx(STOREY_M, abs=0.03)
    # 14 treads of 0.25 m between the floors; the head may step off the side of the last one (the stairwell is open)
    assert 3.0 <= stairs.run_m <= 3.6 and stairs.length_m >= np.hypot(stairs.rise_m, stairs.run_m)
    g = recon.grid
    bottom, top = g.cell_to_world(np.array([stairs.bottom.endpoint, stairs.top.endpoint]))
    assert [*bottom, *top] == pytest.approx([*stairs.bottom.xy, *stairs.top.xy], abs=1e-4)
    assert 1.0 <= bottom[0] <= 1.8 and 0.0 <= bottom[1] <= 1.2  # at the foot of the flight (x 1.75)
    assert 5.0 <= top[0] <= 6.0 and 0.0 <= top[1] <= 1.2  # at its head (x 5.5)
    assert recon.floor(0).navigable[stairs.bottom.endpoint] and recon.floor(1).navigable[stairs.top.endpoint]
    r0, c0, r1, c1 = stairs.flight_bbox
    (x0, y0), (x1, y1) = g.cell_to_world(np.array([[r1, c0], [r0, c1]]))
    assert x0 == pytest.approx(1.75, abs=0.15) and x1 == pytest.approx(5.5, abs=0.3) and y0 >= -0.1 and y1 <= 1.1
    assert summary["stairs"][0]["floors"] == [0, 1]
    # the flight is solid on the floor it rises from (its inside is never seen), a hole on the floor it reaches
    flight = np.zeros((g.rows, g.cols), bool)
    flight[r0 : r1 + 1, c0 : c1 + 1] = True
    assert (recon.floor(0).occupancy[flight] == 2).mean() > 0.9 and summary["cells_occupied_by_stairs"] > 0
    upper = recon.floor(1).navigable[flight].mean()  # the top tread is at the upper floor's level: walkable there
    assert upper < 0.15, upper
    # the stairwell (no railing here) is a void on the upper floor: no solid inferred in its unseen air (was 4 %)
    assert (recon.floor(1).occupancy[flight] == 2).mean() < 0.01


def test_each_floor_sees_its_own_furniture_only(house):
    _, recon, gt = house
    lower_table, upper_table = (gt.instance_footprints(recon.grid) == i for i in (1, 2))
    f0, f1 = recon.floor(0), recon.floor(1)
    assert (f0.occupancy[lower_table] == 2).mean() > 0.8 and (f1.occupancy[upper_table] == 2).mean() > 0.8
    assert (f0.occupancy[upper_table] == 1).mean() > 0.8  # the upper table stands above free lower floor
    assert (f1.occupancy[lower_table] == 1).mean() > 0.8
    assert np.nanmedian(f1.height[upper_table]) == pytest.approx(0.75, abs=0.03)  # above its own floor


def _surface(rng, n, z, x, y):
    xyz = np.c_[rng.uniform(*x, n), rng.uniform(*y, n), np.broadcast_to(z, n)]
    return xyz, np.tile([0.0, 0.0, 1.0], (n, 1))


def _building(rng, *, ramp: bool, table: bool = True):
    # the floors keep 0.5 m off the ramp's side (a wall's width): one enters it at its foot, leaves at its head
    parts = [_surface(rng, 60000, 0.0, (0, 20), (1.5, 4)), _surface(rng, 60000, 3.0, (0, 20), (1.5, 4))]
    parts.append(_surface(rng, 3000, 0.0, (0, 1), (0, 1)))  # the foot of the ramp (the floor under it is hidden)
    if ramp:  # an 18 m ramp along y in [0, 1]: z rises 1 m per 6 m of x (9.5 deg)
        x = rng.uniform(1, 19, 40000)
        parts.append((np.c_[x, rng.uniform(0, 1, 40000), (x - 1) / 6], np.tile([-1 / 6, 0.0, 1.0], (40000, 1))))
        parts.append(_surface(rng, 2000, 3.0, (19, 20), (0, 1)))  # the top landing
    if table:
        parts.append(_surface(rng, 3000, 0.75, (3, 4), (2, 3)))
    xyz = np.concatenate([a for a, _ in parts])
    normals = np.concatenate([b for _, b in parts])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return xyz, normals


FLOORS = [Floor(id=0, name="floor 0", floor_z_m=0.0), Floor(id=1, name="floor 1", floor_z_m=3.0)]
GRID = GridSpec(100, 420, 0.05, (-0.5, 4.5))


def test_a_ramp_is_a_link_and_a_table_is_not():
    rng = np.random.default_rng(0)
    xyz, normals = _building(rng, ramp=True)
    nav = [np.ones((GRID.rows, GRID.cols), bool)] * 2
    (link,) = find_stairs(Surface.of(xyz, normals), FLOORS, GRID, nav, ReconstructParams())
    assert link.kind == "ramp" and link.rise_m == 3.0
    # its ends within floor_tolerance_m (0.05 m: 0.3 m of run) of a floor are that floor
    assert link.run_m == pytest.approx(18.0 - 0.6, abs=0.15)
    assert link.length_m == pytest.approx(np.hypot(17.5, 2.9), abs=0.2)
    assert unlinked_warnings(FLOORS, [link]) == []


def test_floors_without_a_climb_between_them_are_reported():
    rng = np.random.default_rng(1)
    xyz, normals = _building(rng, ramp=False)
    nav = [np.ones((GRID.rows, GRID.cols), bool)] * 2
    links = find_stairs(Surface.of(xyz, normals), FLOORS, GRID, nav, ReconstructParams())
    assert links == []
    (line,) = unlinked_warnings(FLOORS, links)
    assert line.startswith("no stairs or ramp joins floor 0 (0.00 m) and floor 1 (3.00 m)")


def test_a_flight_seen_in_patches_covers_the_ground_between_them_and_no_more():
    # a flight 1 m wide along x: each 0.25 m tread (5 cells) seen in its front 3 cells only; a 0.5 m stretch unseen
    cells = [(r, c) for r in range(10, 30) for c in range(10, 90) if (c - 10) % 5 < 3 and not 50 <= c < 60]
    flight = Flight(0, 1, np.array(cells), np.zeros(len(cells)), np.zeros((40, 100), bool),
                    np.zeros((40, 100), bool), 3.0, 4.0, 4.0)
    footprint = flight.footprint((40, 100), 0.05)
    assert footprint[10:30, 10:48].all() and footprint[10:30, 60:88].all()  # gaps of 0.1 m between treads: joined
    assert not footprint[:, 50:58].any()  # a 0.5 m gap (beyond MAX_GAP_M) stays open
    assert not footprint[:10].any() and not footprint[30:].any() and not footprint[:, 89:].any()
    assert flight.mask((40, 100)).sum() == len(cells)  # the seen cells, as before
