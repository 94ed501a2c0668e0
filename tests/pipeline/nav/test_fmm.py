import numpy as np
import pytest

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


# ----------------------------------------------------------------------------- fast paths = the plain sampling

def _plain_first_blocked(mask, a, b, n):
    from pipeline.nav.fmm import _segments_free

    blocked = np.flatnonzero(~_segments_free(mask, a, b, n))
    return int(blocked[0]) if blocked.size else None


def _walls(rng, shape):
    """A free mask with random wall cells, thin diagonal walls and boxes (corners a diagonal step grazes)."""
    mask = rng.random(shape) > rng.uniform(0.0, 0.08)
    for _ in range(int(rng.integers(0, 6))):
        r, c = int(rng.integers(0, shape[0])), int(rng.integers(0, shape[1]))
        k = int(rng.integers(2, 30))
        rr, cc = np.clip(r + np.arange(k), 0, shape[0] - 1), np.clip(c + np.arange(k), 0, shape[1] - 1)
        mask[rr, cc] = False
        mask[r: r + int(rng.integers(1, 6)), c: c + int(rng.integers(1, 6))] = False
    return mask


def test_first_blocked_gives_the_plain_samplings_verdict():
    from pipeline.nav.fmm import _first_blocked, _sample_count

    rng = np.random.default_rng(7)
    strided = 0
    for _ in range(400):
        shape = (int(rng.integers(10, 90)), int(rng.integers(10, 90)))
        mask = _walls(rng, shape)
        a = np.repeat(rng.integers(0, shape, size=(1, 2)).astype(np.float64), 32, 0)
        b = rng.integers(0, shape, size=(32, 2)).astype(np.float64)
        if rng.random() < 0.5:  # short segments sampled as the batch's far end asks (string pulling's case)
            b = np.clip(a + rng.integers(-6, 7, size=b.shape), 0, np.array(shape) - 1).astype(np.float64)
        if rng.random() < 0.3:  # continuous coordinates, some off the grid
            a, b = a + rng.uniform(-0.6, 0.6, a.shape), b + rng.uniform(-0.6, 0.6, b.shape)
        n = _sample_count(a, b) + int(rng.integers(0, 400))
        strided += (n - 1) // max(float(np.hypot(*(b - a).T).max()), 1.0) >= 4
        assert _first_blocked(mask, a, b, n) == _plain_first_blocked(mask, a, b, n)
    assert strided > 200  # the skipping path was taken


def test_shortcut_keeps_the_cells_the_plain_sampling_keeps():
    from pipeline.nav.fmm import _sample_count, descend, shortcut

    def plain(cells, mask, chunk=32):
        keep, i = [0], 0
        while i < len(cells) - 1:
            later = cells[i + 1:].astype(np.float64)
            start = np.repeat(cells[i: i + 1].astype(np.float64), len(later), 0)
            n, first = _sample_count(start, later), None
            for s in range(0, len(later), chunk):
                blocked = _plain_first_blocked(mask, start[s: s + chunk], later[s: s + chunk], n)
                if blocked is not None:
                    first = s + blocked
                    break
            i = max(i + 1 + (first - 1 if first is not None else len(later) - 1), i + 1)
            keep.append(i)
        return cells[keep]

    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(60):
        shape = (int(rng.integers(40, 160)), int(rng.integers(40, 160)))
        mask = _walls(rng, shape)
        free = np.argwhere(mask)
        goal = np.zeros(shape, bool)
        goal[tuple(free[rng.integers(len(free))])] = True
        fld = geodesic_field(mask, goal, GridSpec(shape[0], shape[1], 0.05, (0.0, 10.0)))
        reach = np.argwhere(np.isfinite(fld))
        for start in reach[rng.integers(0, len(reach), 3)]:
            cells = descend(fld, tuple(start))
            np.testing.assert_array_equal(shortcut(cells, mask), plain(cells, mask))
            checked += len(cells) > 40
    assert checked > 50


def test_one_segment_free_gives_the_plain_samplings_verdict():
    from pipeline.nav.fmm import _sample_count, _segments_free, one_segment_free

    rng = np.random.default_rng(11)
    verdicts = set()
    for _ in range(3000):
        shape = (int(rng.integers(3, 30)), int(rng.integers(3, 30)))
        mask = _walls(rng, shape)
        a = rng.uniform(-1.0, np.array(shape) + 0.5)
        b = a + rng.uniform(-6.0, 6.0, 2)
        a2, b2 = a[None], b[None]
        want = bool(_segments_free(mask, a2, b2, _sample_count(a2, b2))[0])
        assert one_segment_free(mask, *a.tolist(), *b.tolist()) is want
        verdicts.add(want)
    assert verdicts == {True, False}


def test_descend_takes_numpys_steepest_neighbour_ties_and_edges_included():
    from pipeline.nav.fmm import _NEIGHBOURS, _STEPS, descend

    def plain(field, rc):
        rows, cols = field.shape
        r, c = rc
        path = [(r, c)]
        while field[r, c] > 0:
            nb = _NEIGHBOURS + (r, c)
            ok = (nb[:, 0] >= 0) & (nb[:, 0] < rows) & (nb[:, 1] >= 0) & (nb[:, 1] < cols)
            vals = np.full(8, np.inf)
            vals[ok] = field[nb[ok, 0], nb[ok, 1]]
            k = int(np.argmax((field[r, c] - vals) / _STEPS))
            assert vals[k] < field[r, c]
            r, c = r + int(_NEIGHBOURS[k, 0]), c + int(_NEIGHBOURS[k, 1])
            path.append((r, c))
        return np.array(path)

    rng = np.random.default_rng(5)
    for _ in range(40):
        shape = (int(rng.integers(5, 60)), int(rng.integers(5, 60)))
        goal = tuple(int(v) for v in rng.integers(0, shape))
        rr, cc = np.indices(shape)
        # Chebyshev rings: many neighbours tie; walls of inf
        field = np.maximum(abs(rr - goal[0]), abs(cc - goal[1])).astype(np.float64)
        field[(rng.random(shape) < 0.1) & (field > 0)] = np.inf
        for start in np.argwhere(np.isfinite(field))[rng.integers(0, field.size // 2, 5) % np.isfinite(field).sum()]:
            start = tuple(int(v) for v in start)
            try:
                want = plain(field, start)
            except AssertionError:  # walled in: both must give up
                with pytest.raises(ValueError, match="descent stuck"):
                    descend(field, start)
                continue
            np.testing.assert_array_equal(descend(field, start), want)
