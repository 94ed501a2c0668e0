"""Floor estimation, grid placement and the navigable / enclosed-region rules of pipeline.recon.grids."""

import numpy as np
import pytest

from pipeline.config import GridParams, ReconstructParams
from pipeline.errors import ConfigError, StageError
from pipeline.geometry import GridSpec
from pipeline.recon.floors import estimate_floor
from pipeline.recon.grids import column_occupancy, enclosed_unknown, floor_grids, lattice_ratio, navigable_mask, place_grid
from pipeline.recon.surface import Surface


def _plane(rng, n, z, x=(0, 4), y=(0, 3)):
    xyz = np.c_[rng.uniform(*x, n), rng.uniform(*y, n), z + rng.normal(0, 0.004, n)]
    return xyz, np.tile([0.0, 0.0, 1.0], (n, 1))


def test_floor_is_lowest_strong_horizontal_peak_not_the_biggest_or_an_outlier():
    rng = np.random.default_rng(0)
    floor, nf = _plane(rng, 4000, 0.317)
    table, nt = _plane(rng, 6000, 0.75, x=(1, 2), y=(1, 2))  # a bigger peak higher up
    speck, ns = _plane(rng, 30, -0.4)  # a few spurious points below the floor
    wall = np.c_[rng.uniform(0, 4, 3000), np.zeros(3000), rng.uniform(-1, 2, 3000)]
    nw = np.tile([0.0, 1.0, 0.0], (3000, 1))
    xyz = np.concatenate([floor, table, speck, wall])
    normals = np.concatenate([nf, nt, ns, nw])
    z, count = estimate_floor(Surface.of(xyz, normals), camera_z=np.full(5, 1.2))
    assert abs(z - 0.317) < 0.005
    assert count > 3000


def test_no_floor_under_the_cameras_is_a_stage_error():
    rng = np.random.default_rng(1)
    wall = np.c_[rng.uniform(0, 4, 500), np.zeros(500), rng.uniform(0, 2, 500)]
    with pytest.raises(StageError, match="no floor found.*reconstruct.floor_z_m"):
        estimate_floor(Surface.of(wall, np.tile([0.0, 1.0, 0.0], (500, 1))), camera_z=np.ones(3))


def test_grid_is_centred_on_the_surface_and_cell_centres_fall_on_the_voxel_lattice():
    rng = np.random.default_rng(2)
    xyz = np.c_[rng.uniform(10, 14, 1000), rng.uniform(-3, 0, 1000), np.zeros(1000)]
    for voxel in (0.025, 0.05, 0.0125):
        p = ReconstructParams(voxel_size_m=voxel, sdf_trunc_m=0.08)
        grid = place_grid(xyz, GridParams(rows=200, cols=300), p)
        x0, x1, y0, y1 = grid.extent_xy
        assert abs((x0 + x1) / 2 - 12) < 0.1 and abs((y0 + y1) / 2 + 1.5) < 0.1
        centres = grid.cell_to_world(np.array([[0, 0], [17, 123]])) / voxel
        assert np.allclose(centres, np.round(centres), atol=1e-6)


def test_cell_size_must_be_a_multiple_of_the_voxel():
    with pytest.raises(ConfigError, match="grid.cell_size_m .* whole multiple of reconstruct.voxel_size_m"):
        lattice_ratio(GridParams(cell_size_m=0.05), ReconstructParams(voxel_size_m=0.03, sdf_trunc_m=0.08))


def test_navigable_keeps_the_robot_radius_from_occupied_cell_centres():
    occ = np.zeros((21, 21), bool)
    occ[10, 10] = True
    free = ~occ
    nav = navigable_mask(free, occ, cell_size_m=0.05, robot_radius_m=0.18)
    rr, cc = np.mgrid[:21, :21]
    dist = np.hypot(rr - 10, cc - 10) * 0.05
    assert np.array_equal(nav, dist > 0.18)
    assert np.array_equal(navigable_mask(free, np.zeros_like(occ), 0.05, 0.18), free)


def test_only_small_regions_walled_in_by_occupied_cells_are_filled():
    occ = np.zeros((30, 30), bool)
    occ[5:10, 5] = occ[5:10, 9] = occ[5, 5:10] = occ[9, 5:10] = True  # a closed ring: inside 3x3
    occ[20:25, 20] = occ[20:25, 24] = occ[20, 20:25] = True  # open on one side
    free = np.zeros_like(occ)
    free[25:28, 18:27] = True  # the open ring's mouth sees free floor
    filled = enclosed_unknown(occ, free, cell_size_m=0.05, max_area_m2=1.0)
    assert filled.sum() == 9 and filled[6:9, 6:9].all()
    assert not enclosed_unknown(occ, free, cell_size_m=0.05, max_area_m2=0.01).any()


def test_unseen_back_of_furniture_is_inferred_but_the_outside_world_is_not():
    from pipeline.recon.grids import hidden_solid

    occ = np.zeros((40, 40), bool)
    occ[5, 5:35] = occ[35, 5:35] = occ[5:36, 5] = occ[5:36, 34] = True  # building walls
    occ[20, 10:20] = True  # the observed front face of a wardrobe standing against the west wall
    free = np.zeros_like(occ)
    free[21:34, 6:34] = True  # floor seen in front of it
    free[6:15, 6:34] = True  # and in the room's north part
    hidden = hidden_solid(occ, free, cell_size_m=0.05, max_dist_m=0.5)
    # Unknown rows 15-19 lie between the seen floor (row 14) and the face (row 20): each goes to the nearer.
    assert hidden[18:20, 10:20].all() and not hidden[15:18, 10:20].any()
    assert not hidden[:5].any() and not hidden[:, :5].any()  # outside the building stays unknown
    assert not hidden_solid(occ, free, 0.05, 0.0).any()


def test_an_empty_scene_is_a_stage_error_not_an_empty_map():
    from pipeline.recon.grids import placed_grid

    empty = np.zeros((0, 3), np.float32)
    with pytest.raises(StageError, match="frames.zarr: the fused volume has no surface"):
        placed_grid(Surface.of(empty, empty), {0: np.eye(4)}, GridParams(), ReconstructParams(), source="frames.zarr")


def test_furniture_against_an_unseen_outer_wall_is_filled_but_an_unentered_room_is_not():
    from pipeline.recon.grids import building_mask, hidden_solid

    occ = np.zeros((60, 60), bool)
    occ[5, 5:55] = occ[54, 5:55] = occ[5:55, 5] = occ[5:55, 54] = True  # building walls
    occ[5, 20:30] = False  # the north wall behind a wardrobe is never seen ...
    occ[12, 20:30] = occ[5:13, 20] = occ[5:13, 29] = True  # ... only the wardrobe's front and sides
    occ[30, 5:55] = True  # a wall with a room south of it that was never entered
    free = np.zeros_like(occ)
    free[13:30, 6:54] = True
    free[6:12, 6:20] = free[6:12, 30:54] = True
    inside = building_mask(occ, free, cell_size_m=0.05, closing_m=1.0)
    assert inside[6:12, 21:29].all() and not inside[:4].any() and not inside[:, :4].any()
    hidden = hidden_solid(occ, free, 0.05, 0.5, closing_m=1.0, max_region_m2=1.0)
    assert hidden[6:12, 21:29].all()  # the wardrobe's unseen inside, though it touches the outside world
    assert not hidden[31:54].any()  # the room never entered (2.3 m^2 unknown) stays unknown
    assert not hidden[:5].any()


def test_column_occupancy_reads_cell_centre_columns_and_sees_low_air_behind_furniture():
    # 4x4 cells of 5 cm, voxels of 2.5 cm: the centre of cell (r, c) is lattice (2c + 1, 7 - 2r).
    grid = GridSpec(4, 4, 0.05, (0.0, 0.2))
    p = ReconstructParams()
    lattice = np.array([
        [1, 7, 12],    # cell (0, 0), 0.30 m, behind a surface: occupied
        [3, 5, 12],    # cell (1, 1), 0.30 m, in front of a surface: air low above the floor was seen
        [5, 3, 40],    # cell (2, 2), 1.00 m, in front of a surface: above hidden_free_max_height_m
        [7, 1, 0],     # cell (3, 3), on the floor: floor seen
        [6, 1, 12],    # between cell centres: ignored
    ], dtype=np.int32)
    tsdf = np.array([-0.4, 0.6, 0.6, -0.1, -0.9], dtype=np.float32)
    columns = column_occupancy(grid, 0.0, [(lattice, tsdf)], p)
    assert np.argwhere(columns.occupied).tolist() == [[0, 0]]
    assert np.argwhere(columns.low_air).tolist() == [[1, 1]]
    assert np.argwhere(columns.floor_seen).tolist() == [[3, 3]]
    assert np.allclose(columns.solid_z[0, 0], 0.3) and np.isnan(columns.solid_z[1:]).all()


def _column(cell_rc, levels_tsdf, grid):
    """Lattice voxels of one cell-centre column (see the lattice note above) at ``{level: tsdf}``."""
    r, c = cell_rc
    lattice = np.array([[2 * c + 1, 2 * (grid.rows - r) - 1, k] for k in levels_tsdf], dtype=np.int32)
    return lattice, np.array(list(levels_tsdf.values()), dtype=np.float32)


def test_a_thin_top_seen_only_from_above_occupies_its_cell_but_a_face_beside_the_cell_does_not():
    grid = GridSpec(4, 4, 0.05, (0.0, 0.2))
    p = ReconstructParams()  # voxels 2.5 cm: a 4 cm table top at 0.72-0.76 m holds level 29 (0.725 m)
    # Cell (0, 0): a table top seen at grazing angles. Its inside (level 29) was never updated; the
    # voxel above the board is close in front of it, the air above that farther; the space under
    # the table was seen empty from the side.
    top = _column((0, 0), {24: 1.0, 25: 1.0, 26: 1.0, 30: 0.5, 31: 1.0, 32: 1.0}, grid)
    # Cell (1, 1): a wall face passing just outside the cell centre: tsdf small and constant upward,
    # the column under it seen too except one level (an occluded strip).
    face = _column((1, 1), {12: 0.1, 13: 0.1, 15: 0.1, 16: 0.1, 17: 0.1}, grid)
    # Cell (2, 2): the floor (level 0) seen through free space: the band starts at 0.1 m.
    floor = _column((2, 2), {0: -0.1, 1: 0.3, 2: 0.6, 3: 1.0}, grid)
    # Cell (3, 3): air everywhere.
    air = _column((3, 3), {k: 1.0 for k in range(4, 60)}, grid)
    chunks = [top, face, floor, air]
    columns = column_occupancy(grid, 0.0, chunks, p)
    assert np.argwhere(columns.occupied).tolist() == [[0, 0]]
    assert np.allclose(columns.solid_z[0, 0], 0.725)  # the board, under the voxel in front of it
    assert np.argwhere(columns.tops_only).tolist() == [[0, 0]]
    # The rule looks across chunk boundaries: the voxel above the top in another chunk still counts.
    split = [(top[0][:4], top[1][:4]), (top[0][4:], top[1][4:])]
    assert column_occupancy(grid, 0.0, split, p).occupied[0, 0]
    # A top whose inside was observed behind the surface is occupied by the plain column test;
    # one with the voxel below seen in front of a surface (air under a sheet seen edge-on) is not a top.
    seen_inside = _column((0, 0), {29: -0.3, 30: 0.5, 31: 1.0}, grid)
    air_below = _column((0, 0), {29: 0.9, 30: 0.5, 31: 1.0}, grid)
    assert column_occupancy(grid, 0.0, [seen_inside], p).occupied[0, 0]
    assert column_occupancy(grid, 0.0, [_column((0, 0), {29: -0.3}, grid)], p).occupied[0, 0]  # nothing in front
    assert not column_occupancy(grid, 0.0, [air_below], p).occupied.any()


def test_an_unseen_board_between_seen_air_is_solid_where_it_spans_a_patch():
    grid = GridSpec(20, 20, 0.05, (0.0, 1.0))  # cell (r, c) centre: lattice (2c + 1, 39 - 2r)
    p = ReconstructParams()

    def columns(cells, levels_tsdf):
        lattice = np.array([[2 * c + 1, 39 - 2 * r, k] for r, c in cells for k in levels_tsdf], dtype=np.int32)
        return lattice, np.tile(np.array(list(levels_tsdf.values()), np.float32), len(cells))

    # A table top at 0.70-0.74 m over 12 x 12 cells (0.36 m^2): levels 28 and 29 never observed, the
    # air above and under it seen only at angles so grazing that it reads far from any surface.
    board = {k: 1.0 for k in (*range(20, 28), 30, 31, 32)}
    table = [(r, c) for r in range(2, 14) for c in range(2, 14)]
    lone = [(17, 17)]  # the same gap in one cell: no board
    # Under a shelf: air seen above, a tall unobserved run (the shadow of furniture), air low down.
    shadow = [(r, c) for r in range(15, 20) for c in range(2, 14)]
    chunks = [columns(table, board), columns(lone, board), columns(shadow, {k: 1.0 for k in (*range(4, 10), 30, 31)})]
    occupied = column_occupancy(grid, 0.0, chunks, p).occupied
    assert occupied[2:14, 2:14].all()
    assert occupied.sum() == len(table)
    # The same patch with its gaps at heights 10 cm apart row by row: no flat board, nothing solid.
    low = {k: 1.0 for k in (*range(20, 24), 26, 27, 28)}  # the gap at levels 24-25 instead of 28-29
    rows = [columns([(r, c) for c in range(2, 14)], board if r % 2 else low) for r in range(2, 14)]
    assert not column_occupancy(grid, 0.0, rows, p).occupied.any()


def test_a_large_floor_grows_the_grid_in_whole_tiles_and_one_that_fits_keeps_it():
    rng = np.random.default_rng(7)
    p = ReconstructParams()
    office = np.c_[rng.uniform(-50, 50, 20000), rng.uniform(-30, 30, 20000), np.zeros(20000)]
    grid = place_grid(office, GridParams(), p)  # 100 x 60 m (+1 m each side) in 128-cell tiles of 6.4 m
    assert (grid.rows, grid.cols) == (1280, 2048) and grid.rows * 0.05 >= 62 and grid.cols * 0.05 >= 102
    x0, x1, y0, y1 = grid.extent_xy
    assert x0 < -50.5 and x1 > 50.5 and y0 < -30.5 and y1 > 30.5
    flat = office / np.array([5.0, 5.0, 1.0])  # 20 x 12 m fits the default 30 x 30 m grid: kept as it is
    assert place_grid(flat, GridParams(), p) == place_grid(flat, GridParams(extent="fixed"), p)
    assert (place_grid(office, GridParams(extent="fixed"), p).rows, grid.cols) == (600, 2048)
    pinned = place_grid(office, GridParams(centre_xy=(0.0, 0.0)), p)  # a pinned fold never moves
    assert (pinned.rows, pinned.cols) == (600, 600)
    with pytest.raises(ConfigError, match="grid.extent: the surface spans 19.. x 59 m, a grid of 1280 x 39680 cells.*grid.extent: fixed"):
        place_grid(office * np.array([20.0, 1.0, 1.0]), GridParams(), p)


def _ringed_hole(void: bool):
    """A 20 x 20 cell floor seen everywhere but a 6 x 6 hole ringed by a seen railing (0.3 m high): the grids of
    :func:`floor_grids`, with the hole given as ``void`` or not."""
    grid = GridSpec(20, 20, 0.05, (0.0, 1.0))
    inside = np.zeros((20, 20), bool)
    inside[7:13, 7:13] = True
    ring = np.zeros((20, 20), bool)
    ring[6:14, 6:14] = True
    ring &= ~inside
    voxels = [_column(rc, {12: -0.4} if ring[rc] else {0: -0.1}, grid) for rc in zip(*np.nonzero(~inside))]
    lattice, tsdf = np.concatenate([v[0] for v in voxels]), np.concatenate([v[1] for v in voxels])
    xyz = np.c_[np.random.default_rng(0).uniform(0.05, 0.95, (200, 2)), np.zeros(200)]
    normals = np.tile([0.0, 0.0, 1.0], (200, 1))
    return floor_grids(grid, 0.0, Surface.of(xyz, normals), [(lattice, tsdf)], ReconstructParams(),
                       void=inside if void else None), ring, inside


def test_a_stairwell_void_gets_no_inferred_solid_but_what_was_seen_in_it_counts():
    # the same unseen hole: the inside of a cabinet (filled) unless it is the stairwell over a flight (left unknown)
    grids, ring, inside = _ringed_hole(void=False)
    assert (grids.occupancy[inside] == 2).all() and (grids.occupancy[ring] == 2).all()
    grids, ring, inside = _ringed_hole(void=True)
    assert (grids.occupancy[inside] == 0).all() and (grids.occupancy[ring] == 2).all()
    assert (grids.occupancy[~inside & ~ring] == 1).all() and not grids.navigable[inside].any()
