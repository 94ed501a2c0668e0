"""Per-cell figures from the surface points (pipeline.recon.cell_surface): points per cell, the face test (on all
the points and tile by tile) and the highest point of each cell (at once and chunk by chunk)."""

import numpy as np

from pipeline.config import ReconstructParams
from pipeline.geometry import GridSpec
from pipeline.recon.cell_surface import TopSurface, faces_cleared, in_front_of_faces, surface_occupancy, top_surface
from pipeline.recon.surface import Surface
from tests.pipeline.recon.test_surface import tiled_surface


def test_surface_points_need_several_to_occupy_a_cell():
    grid = GridSpec(4, 4, 0.05, (0.0, 0.2))
    p = ReconstructParams()
    # A face at x = 0.078 m, normal +x, inside toward -x: moved half a cell in, points land in
    # cell column 1 (x 0.05-0.10); two stray points of a face at x = 0.128 land in column 2.
    face = np.c_[np.full(5, 0.078), np.linspace(0.06, 0.14, 5), np.full(5, 0.5)]
    stray = np.array([[0.128, 0.11, 0.5], [0.128, 0.11, 0.7]])
    xyz = np.vstack([face, stray])
    normals = np.tile([1.0, 0.0, 0.0], (len(xyz), 1))
    occ = surface_occupancy(grid, 0.0, xyz, normals, p)
    assert p.surface_min_points == 3
    assert occ[:, 1].sum() >= 1 and not occ[:, 2].any()
    assert surface_occupancy(grid, 0.0, xyz, normals, p.model_copy(update={"surface_min_points": 1}))[:, 2].any()


def _face(x, y, z_lo, z_hi, normal=(1.0, 0.0, 0.0)):
    """Surface points of a vertical face at ``x`` (lattice-spaced over y +- 1 cm and heights), with their normal."""
    ys, zs = np.meshgrid(y + np.array([-0.01, 0.0, 0.01]), np.arange(z_lo, z_hi + 1e-9, 0.025))
    xyz = np.c_[np.full(ys.size, x), ys.ravel(), zs.ravel()]
    return xyz, np.tile(normal, (len(xyz), 1))


def test_a_face_passing_just_outside_a_cell_centre_clears_the_cell_unless_solid_was_seen_elsewhere_in_it():
    grid = GridSpec(4, 4, 0.05, (0.0, 0.2))  # cell (r, c) centre: x = 0.025 + 0.05 c, y = 0.175 - 0.05 r
    p = ReconstructParams()
    faces = [
        _face(0.070, 0.125, 0.1, 1.5),   # cell (1, 1): solid at x < 0.070, the centre 5 mm in front
        _face(0.130, 0.125, 0.1, 1.5),   # cell (1, 2): solid at x < 0.130, the centre 5 mm inside
        _face(0.070, 0.075, 0.45, 0.6),  # cell (2, 1): a backrest face above a seat seen solid below it
        _face(0.120, 0.075, 0.1, 1.5),   # cell (2, 2): in front of a face, but a top lies over the centre
        (np.array([[0.125, 0.075, 0.7]]), np.array([[0.0, 0.0, 1.0]])),
    ]
    xyz = np.vstack([f[0] for f in faces])
    normals = np.vstack([f[1] for f in faces])
    candidates = np.zeros((4, 4), bool)
    candidates[1:3, 1:3] = True
    solid_z = np.full((4, 4, 2), np.nan, np.float32)
    solid_z[1, 1] = (0.2, 1.4)  # spurious solid along the face's whole height
    solid_z[2, 1] = (0.1, 0.4)  # the seat, below the backrest's face
    cleared = in_front_of_faces(grid, 0.0, xyz, normals, candidates, solid_z, p)
    assert np.argwhere(cleared).tolist() == [[1, 1]]


def test_every_face_point_in_reach_votes_so_the_order_of_the_points_does_not_matter():
    # A convex corner's edge: 70 side points stacked at one xy, 1 cm from the centre of cell (1, 1), all
    # at exactly the same distance. 36 on the face the centre lies in front of (+6 mm), 34 on the other
    # (-10 mm): the median of all of them is positive. A cap on the neighbour count would keep some of
    # the tied points and drop others by their position in the array (open3d's hash-map order).
    grid = GridSpec(4, 4, 0.05, (0.0, 0.2))
    centre = grid.cell_to_world(np.array([[1, 1]]))[0]
    n = 70
    xyz = np.c_[np.full(n, centre[0] + 0.01), np.full(n, centre[1]), np.linspace(0.15, 1.45, n)]
    normals = np.where((np.arange(n) < 36)[:, None], [-0.6, 0.8, 0.0], [1.0, 0.0, 0.0])
    candidates = np.zeros((4, 4), bool)
    candidates[1, 1] = True
    solid_z = np.full((4, 4, 2), np.nan, np.float32)
    rng = np.random.default_rng(0)
    for _ in range(12):
        perm = rng.permutation(n)
        cleared = in_front_of_faces(grid, 0.0, xyz[perm], normals[perm], candidates, solid_z, ReconstructParams())
        assert np.argwhere(cleared).tolist() == [[1, 1]]


def test_the_face_test_tile_by_tile_reads_the_neighbours_points_within_reach(tmp_path):
    # faces along the tile boundaries x = 1 and y = 1: each cell centre beside them votes with points of two tiles
    rng = np.random.default_rng(3)
    grid = GridSpec(40, 40, 0.05, (0.0, 2.0))
    y = rng.uniform(0.0, 2.0, 4000)
    z = rng.uniform(0.15, 1.4, 4000)
    x = np.where(np.arange(4000) % 2, 1.0 + rng.normal(0, 0.01, 4000), rng.uniform(0, 2, 4000))
    y = np.where(np.arange(4000) % 2, y, 1.0 + rng.normal(0, 0.01, 4000))
    xyz = np.c_[x, y, z].astype(np.float32)
    normals = np.where((np.arange(4000) % 2)[:, None] == 1, [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]).astype(np.float32)
    candidates = np.ones((40, 40), bool)
    solid_z = np.full((40, 40, 2), np.nan, np.float32)
    p = ReconstructParams()
    whole = in_front_of_faces(grid, 0.0, xyz, normals, candidates, solid_z, p)
    surface = tiled_surface(xyz, normals, np.zeros_like(xyz, np.uint8), tmp_path)
    assert whole.sum() > 20
    np.testing.assert_array_equal(faces_cleared(grid, 0.0, surface, None, candidates, solid_z, p), whole)
    np.testing.assert_array_equal(faces_cleared(grid, 0.0, Surface.of(xyz, normals), None, candidates, solid_z, p),
                                  whole)


def test_the_highest_point_of_each_cell_chunk_by_chunk_is_that_of_all_points_in_any_order():
    rng = np.random.default_rng(5)
    grid = GridSpec(10, 10, 0.05, (0.0, 0.5))
    xyz = np.c_[rng.uniform(-0.1, 0.6, (5000, 2)), np.round(rng.uniform(0, 3, 5000), 1)].astype(np.float32)
    colors = rng.integers(0, 3, (5000, 3)).astype(np.uint8)  # ties in height broken by colour
    p = ReconstructParams()
    height, color, outside = top_surface(grid, 0.0, xyz, colors, p)
    assert outside > 0 and np.isfinite(height).any() and np.nanmax(height) <= p.height_max_m
    for seed in range(3):
        perm = np.random.default_rng(seed).permutation(len(xyz))
        top = TopSurface(grid, 0.0, p)
        for part in np.array_split(perm, 7):
            top.add(xyz[part], colors[part])
        h, c, n = top.result()
        np.testing.assert_array_equal(h, height)
        np.testing.assert_array_equal(c, color)
        assert n == outside
