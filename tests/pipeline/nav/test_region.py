"""The shared goal region: distance + line of sight, route targets, episodes that never end behind a wall."""

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.config import TaskParams
from pipeline.routes.episodes import GoalTarget, make_episodes
from pipeline.nav.fmm import geodesic_field
from pipeline.nav.region import MeshSight, goal_region, route_target
from pipeline.nav.verify import replay

GRID = GridSpec(80, 80, 0.05, (0.0, 4.0))  # 4 m x 4 m, origin at the north-west corner


def _room_with_wall():
    """Navigable everywhere but a wall along column 40 (x = 2 m) with a door at rows 5..14 (far north)."""
    nav = np.zeros((80, 80), bool)
    nav[2:78, 2:78] = True
    wall = np.zeros_like(nav)
    wall[:, 39:41] = True
    wall[5:15, 39:41] = False
    nav &= ~wall
    obj = np.zeros_like(nav)
    obj[50:54, 42:46] = True  # object just east of the wall, south
    nav &= ~obj
    return nav, wall, obj


def _grid_sight(wall):
    """A hand-made line of sight for the tests: blocked when the segment crosses a wall cell."""
    def sight(origins_xy, target_xy, z_levels, own):
        out = []
        for o in np.asarray(origins_xy):
            t = np.linspace(0, 1, 60)[:, None]
            rc = GRID.world_to_cell(o[None] + (np.asarray(target_xy)[None] - o[None]) * t)
            out.append(not wall[rc[:, 0], rc[:, 1]].any())
        return np.array(out, bool)
    return sight


def test_region_excludes_cells_behind_the_wall():
    nav, wall, obj = _room_with_wall()
    centre = GRID.cell_to_world(np.array([51.5, 43.5]))
    region = goal_region(nav, obj, GRID, centre, [0.3, 0.6], _grid_sight(wall), success_m=1.5)
    rr, cc = np.nonzero(region)
    assert region.sum() > 100 and (cc > 40).all()  # all on the object's side of the wall
    behind = nav & ~region
    behind[:, 40:] = False
    # west of the wall there are navigable cells within 1.5 m of the object: none is in the region
    from scipy import ndimage

    d = ndimage.distance_transform_edt(~obj) * GRID.cell_size_m
    assert (behind & (d <= 1.5)).sum() > 50
    target = route_target(region, obj, GRID, stop_radius_m=1.0)
    assert target.any() and not (target & ~region).any()


def test_episodes_end_in_region_and_reject_behind_wall():
    nav, wall, obj = _room_with_wall()
    centre = GRID.cell_to_world(np.array([51.5, 43.5]))
    region = goal_region(nav, obj, GRID, centre, [0.3, 0.6], _grid_sight(wall), success_m=1.5)
    fp = [GRID.cell_to_world(np.array([[50, 42], [50, 45], [53, 45], [53, 42]]))]
    goal = GoalTarget("g", obj, fp, centre, None, region)
    eps = make_episodes(nav, GRID, [goal], episodes_per_goal=3, min_geodesic_m=1.0, seed=0,
                        task=TaskParams(clearance_m=0.05))
    assert eps.episodes and not eps.unreachable
    for e in eps.episodes:
        end = GRID.world_to_cell(e.path_xy[-1])
        assert region[end[0], end[1]] and end[1] > 40
        # l is the geodesic distance to the REGION, never longer than the stored route
        assert e.geodesic_m <= e.path_length_m + 0.1
    # standing just west of the wall, 1 m from the object, facing it: close enough but not in sight
    west = GRID.cell_to_world(np.array([51, 36]))
    res = replay(np.array([0], np.uint8), (west[0], west[1], 0.0), nav, GRID, fp, region=region, face_xy=centre,
                 hfov_deg=90.0)
    assert res.distance_to_goal_m <= 1.5 and not res.in_region and not res.success
    res = replay(np.array([0], np.uint8), (west[0], west[1], 0.0), nav, GRID, fp)  # without the region: accepted
    assert res.success


def test_empty_region_is_flagged_unreachable():
    nav, wall, obj = _room_with_wall()
    centre = GRID.cell_to_world(np.array([51.5, 43.5]))
    region = goal_region(nav, obj, GRID, centre, [0.3], lambda o, t, z, own: np.zeros(len(o), bool))
    assert not region.any()
    goal = GoalTarget("g", obj, [], centre, None, region)
    eps = make_episodes(nav, GRID, [goal], episodes_per_goal=2, min_geodesic_m=1.0, seed=0)
    assert not eps.episodes and eps.unreachable[0]["goal"] == "g"
    assert eps.unreachable[0]["reason"].startswith("empty goal region")


def test_geodesic_field_target_without_zero_contour_is_not_a_crash():
    # a target cell whose free neighbours are all masked: scikit-fmm finds no zero contour
    nav = np.zeros((20, 20), bool)
    nav[2:8, 2:8] = True
    nav[15, 15] = True
    target = np.zeros_like(nav)
    target[15, 15] = True
    f = geodesic_field(nav, target, GridSpec(20, 20, 0.05, (0.0, 1.0)))
    assert f[15, 15] == 0 and np.isinf(f[nav & ~target]).all()


def test_mesh_sight_blocks_behind_a_box():
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(0.1, 2.0, 2.0)  # a wall x in [2.0, 2.1], y in [1, 3], z in [0, 2]
    box.translate((2.0, 1.0, 0.0))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(box.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(box.triangles, np.uint32)))
    sight = MeshSight(scene, cam_z=0.9, floor_z=0.0, grid=GRID)
    own = np.zeros((80, 80), bool)
    seen = sight(np.array([[1.0, 2.0], [3.0, 2.0], [1.0, 3.9]]), (3.5, 2.0), [0.5], own)
    assert seen.tolist() == [False, True, True]
