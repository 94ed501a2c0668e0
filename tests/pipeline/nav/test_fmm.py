import numpy as np

from pipeline.geometry import GridSpec
from pipeline.nav.fmm import geodesic_field, planning_mask, shortest_path, target_region
from tests.fixtures.goal_scenes import corridor_grid


def test_geodesic_around_the_corner_matches_the_l_shaped_length():
    nav, grid = corridor_grid()
    goal = np.zeros_like(nav)
    goal[grid.world_to_cell(np.array([5.5, 4.8]))[0], grid.world_to_cell(np.array([5.5, 4.8]))[1]] = True
    fld = geodesic_field(nav, goal, grid)
    path = shortest_path(fld, nav, grid, np.array([0.3, 0.5]))
    # the true shortest path touches the inner corner (5, 1): |(0.3,0.5)-(5,1)| + |(5,1)-(5.5,4.8)|
    exact = np.hypot(4.7, 0.5) + np.hypot(0.5, 3.8)
    assert abs(path.geodesic_m - exact) < 0.1 and abs(path.length_m - exact) < 0.1
    assert nav[tuple(grid.world_to_cell(path.polyline_xy).T)].all()


def test_unreachable_and_clearance():
    grid = GridSpec(rows=20, cols=40, cell_size_m=0.05, origin_xy=(0.0, 1.0))
    nav = np.ones((20, 40), bool)
    nav[:, 20] = False  # a wall splits the grid
    goal = np.zeros_like(nav)
    goal[10, 30] = True
    fld = geodesic_field(nav, goal, grid)
    assert np.isinf(fld[10, 5]) and np.isfinite(fld[10, 35])
    assert shortest_path(fld, nav, grid, grid.cell_to_world(np.array([10, 5]))) is None
    plan = planning_mask(nav, grid, 0.1)
    assert not plan[:, 18:23].any() and plan[10, 10] and not plan[0].any()
    assert target_region(plan, goal, grid, 0.2)[10, 30 - 4] and not target_region(plan, goal, grid, 0.2)[10, 25]


def test_enclosed_target_reaches_only_itself():
    grid = GridSpec(rows=10, cols=10, cell_size_m=0.05, origin_xy=(0.0, 0.5))
    nav = np.ones((10, 10), bool)
    nav[3:6, 3:6] = False
    nav[4, 4] = True  # a pocket walled in on all sides
    goal = np.zeros_like(nav)
    goal[4, 4] = True
    fld = geodesic_field(nav, goal, grid)
    assert fld[4, 4] == 0 and np.isinf(np.delete(fld.ravel(), 44)).all()


def _random_masks(n: int, seed: int):
    """``(grid, mask, target)`` triples: random free masks (some opened into rooms, some speckled, with
    diagonal-only contacts) and targets of a few small boxes, some off the mask."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    for trial in range(n):
        shape = tuple(int(v) for v in rng.integers(5, 50, 2))
        grid = GridSpec(shape[0], shape[1], 0.05, (0.0, 5.0))
        mask = rng.random(shape) < rng.uniform(0.3, 0.9)
        if trial % 3 == 0:
            mask = ndimage.binary_opening(mask)
        target = np.zeros(shape, bool)
        for _ in range(int(rng.integers(1, 5))):
            r, c = int(rng.integers(0, shape[0])), int(rng.integers(0, shape[1]))
            target[r: r + int(rng.integers(1, 4)), c: c + int(rng.integers(1, 4))] = True
        yield grid, mask, target


def test_reachable_is_where_the_marched_field_is_finite():
    from pipeline.nav.fmm import reachable

    for grid, mask, target in _random_masks(100, seed=4):
        np.testing.assert_array_equal(reachable(mask, target), np.isfinite(geodesic_field(mask, target, grid)))
    # pockets joined only diagonally are apart, as for the marching stencil
    mask = np.zeros((6, 6), bool)
    mask[1, 1] = mask[2, 2] = True
    target = np.zeros_like(mask)
    target[1, 1] = True
    assert reachable(mask, target).tolist() == np.isfinite(geodesic_field(mask, target, GridSpec(6, 6, 0.05, (0, 1)))
                                                            ).tolist()
    assert not reachable(mask, target)[2, 2]


def test_target_region_on_the_footprints_box_is_the_whole_grids():
    from scipy import ndimage

    for grid, mask, target in _random_masks(40, seed=5):
        for radius in (0.0, 0.05, 0.12, 0.5, 3.0):
            whole = mask & (ndimage.distance_transform_edt(~target) * grid.cell_size_m <= radius)
            np.testing.assert_array_equal(target_region(mask, target, grid, radius), whole)
