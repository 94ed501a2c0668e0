"""Line of sight read a window at a time (:mod:`pipeline.nav.sight`): the same answers as ray casting the whole
mesh, on a floor many windows wide, from a canonical recon mesh (strips) and from any other PLY (a full read)."""

import numpy as np
import open3d as o3d
import pytest

from pipeline.errors import ArtifactError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.nav.region import MeshSight, group_region, own_cells, sight_levels, sight_window
from pipeline.nav.sight import STRIP_MARGIN_M, PlyLayout, WindowedSight, read_windows
from pipeline.recon.store import write_mesh

GRID = GridSpec(rows=280, cols=880, cell_size_m=0.05, origin_xy=(-2.0, 12.0))  # x -2..42 m, y -2..12 m
CAM_H = 0.9


def _boxes() -> tuple[np.ndarray, np.ndarray]:
    """A 40 m x 10 m floor: outer walls, a wall every 8 m with a door, and furniture boxes (mins, maxs)."""
    rng = np.random.default_rng(3)
    lo = [(-0.1, -0.1, 0), (-0.1, 10, 0), (-0.1, 0, 0), (40, 0, 0), (0, 0, -0.05)]
    hi = [(40.1, 0, 2.5), (40.1, 10.1, 2.5), (0, 10, 2.5), (40.1, 10, 2.5), (40, 10, 0)]
    for x in range(8, 40, 8):
        lo += [(x, 0, 0), (x, 6, 0)]
        hi += [(x + 0.1, 5, 2.5), (x + 0.1, 10, 2.5)]
    for _ in range(40):
        x, y = rng.uniform(0.5, 39), rng.uniform(0.5, 9)
        w, d, h = rng.uniform(0.3, 1.2, 3)
        lo.append((x, y, 0))
        hi.append((x + w, y + d, h))
    return np.asarray(lo, np.float64), np.asarray(hi, np.float64)


def _box_mesh(lo: np.ndarray, hi: np.ndarray, step: float) -> o3d.geometry.TriangleMesh:
    """The boxes' surfaces cut into triangles at most ``step`` metres across (as marching cubes' are small)."""
    mesh = o3d.geometry.TriangleMesh()
    for a, b in zip(lo, hi):
        box = o3d.geometry.TriangleMesh.create_box(*(b - a))
        box.translate(a)
        while np.ptp(np.asarray(box.vertices)[np.asarray(box.triangles)], axis=1).max() > step:
            box = box.subdivide_midpoint(1)
        mesh += box
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.full((len(mesh.vertices), 3), 0.5))
    return mesh


@pytest.fixture(scope="module")
def floor(tmp_path_factory):
    """``(canonical recon mesh path, the same mesh written by open3d as it comes, the whole-mesh sight)``."""
    tmp = tmp_path_factory.mktemp("sight")
    mesh = _box_mesh(*_boxes(), step=0.5)
    canonical = tmp / "recon_mesh.ply"
    write_mesh(canonical, mesh)
    plain = tmp / "plain.ply"
    o3d.io.write_triangle_mesh(str(plain), o3d.io.read_triangle_mesh(str(canonical)))
    return canonical, plain, MeshSight.from_mesh(canonical, floor_z=0.0, camera_height_m=CAM_H, grid=GRID)


def _queries(n: int, seed: int):
    """Random goal-region-like queries: cells within 2 m of a target, the target's column at two heights."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        target = rng.uniform((0.5, 0.5), (39.5, 9.5))
        origins = target + rng.uniform(-2.0, 2.0, (200, 2))
        own = np.zeros((GRID.rows, GRID.cols), bool)
        rc = GRID.world_to_cell(target)
        own[rc[0] - 3: rc[0] + 4, rc[1] - 3: rc[1] + 4] = True
        yield origins, target, rng.uniform(0.1, 1.2, 2), own


@pytest.mark.parametrize("which", ["canonical", "plain"])
def test_windowed_sight_answers_as_the_whole_mesh_does(floor, which):
    canonical, plain, whole = floor
    sight = WindowedSight(canonical if which == "canonical" else plain, floor_z=0.0, camera_height_m=CAM_H, grid=GRID)
    blocked = seen = 0
    for origins, target, levels, own in _queries(30, seed=1):
        for every in (False, True):
            got = sight(origins, target, levels, own, every=every)
            np.testing.assert_array_equal(got, whole(origins, target, levels, own, every=every))
            seen, blocked = seen + int(got.sum()), blocked + int((~got).sum())
    assert seen > 1000 and blocked > 1000  # walls and furniture hide some cells, not all
    assert sight.reads == 30  # no window was prepared: each query read its own, once


def test_goal_regions_from_prepared_windows_are_the_whole_meshs(floor):
    canonical, _, whole = floor
    nav = np.ones((GRID.rows, GRID.cols), bool)
    lo, hi = _boxes()
    objects = {}
    index = np.zeros((GRID.rows, GRID.cols), np.int32)
    keys = [f"box_{i}" for i in range(len(lo) - 13)]  # the furniture, across every room of the floor

    class Obj:
        def __init__(self, a, b):
            self.mass_center, self.z_range = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2), (0.0, float(b[2]))

    for i, k in enumerate(keys):
        a, b = lo[13 + i], hi[13 + i]
        r0, c0 = GRID.world_to_cell(np.array([a[0], b[1]]))
        r1, c1 = GRID.world_to_cell(np.array([b[0], a[1]]))
        index[r0: r1 + 1, c0: c1 + 1] = i + 1
        objects[k] = Obj(a, b)
    groups = [(keys[0], keys[1]), (keys[5],), (keys[12],), (keys[20], keys[21]), (keys[33],)]
    sight = WindowedSight(canonical, floor_z=0.0, camera_height_m=CAM_H, grid=GRID)
    sight.prepare([sight_window(index == keys.index(k) + 1, GRID, objects[k].mass_center) for g in groups for k in g])
    assert sight.reads == 1
    for g in groups:
        got = group_region(nav, index, keys, g, objects, GRID, sight)
        want = group_region(nav, index, keys, g, objects, GRID, whole)
        assert got.any() and not got.all()
        np.testing.assert_array_equal(got, want)
    assert sight.reads == 1  # every query fell in a prepared window
    # the windows hold the mesh around the goals: a small part of the floor's triangles
    held = sum(len(w.triangles) for w in sight.windows)
    assert held < 0.35 * len(np.asarray(o3d.io.read_triangle_mesh(str(canonical)).triangles))


def test_a_window_holds_every_triangle_meeting_it(floor):
    canonical, plain, _ = floor
    mesh = o3d.io.read_triangle_mesh(str(canonical))
    v, t = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.triangles)
    box = (11.3, 2.2, 15.9, 7.1)
    xy = v[t][:, :, :2]
    meets = (xy[:, :, 0].max(1) >= box[0]) & (xy[:, :, 0].min(1) <= box[2]) & \
            (xy[:, :, 1].max(1) >= box[1]) & (xy[:, :, 1].min(1) <= box[3])
    want = {tuple(tr) for tr in v[t[meets]].reshape(-1, 9).tolist()}
    for path in (canonical, plain):
        (w,) = read_windows(path, [box])
        assert {tuple(tr) for tr in w.vertices[w.triangles].reshape(-1, 9).tolist()} == want


def test_a_mesh_with_long_triangles_is_read_in_full_with_the_same_windows(tmp_path):
    lo, hi = _boxes()
    long = _box_mesh(lo, hi, step=4 * STRIP_MARGIN_M)  # triangles longer than the strip margin: not canonical
    path = tmp_path / "recon_mesh.ply"
    write_mesh(path, long)
    box = (20.2, 1.0, 23.0, 4.0)
    (w,) = read_windows(path, [box])
    mesh = o3d.io.read_triangle_mesh(str(path))
    v, t = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.triangles)
    xy = v[t][:, :, :2]
    meets = (xy[:, :, 0].max(1) >= box[0]) & (xy[:, :, 0].min(1) <= box[2]) & \
            (xy[:, :, 1].max(1) >= box[1]) & (xy[:, :, 1].min(1) <= box[3])
    assert len(w.triangles) == int(meets.sum()) > 0


def test_own_cells_and_sight_window_hold_the_regions_rays():
    obj = np.zeros((GRID.rows, GRID.cols), bool)
    obj[100:104, 300:310] = True
    centre = GRID.cell_to_world(np.array([101.5, 304.5]))
    x0, y0, x1, y1 = sight_window(obj, GRID, centre, success_m=1.5)
    pad = 1.5 + 0.05  # the region's cells reach success_m (+ a cell) beyond the footprint
    fx0, fy1 = GRID.cell_to_world(np.array([100, 300]))
    fx1, fy0 = GRID.cell_to_world(np.array([103, 309]))
    assert x0 <= fx0 - 1.5 and x1 >= fx1 + 1.5 and y0 <= fy0 - 1.5 and y1 >= fy1 + 1.5
    assert x1 - x0 <= (fx1 - fx0) + 2 * pad + 0.1
    assert own_cells(obj).sum() > obj.sum() and sight_levels((0.0, 1.0)).tolist() == [0.5, 1.0]
    assert sight_window(np.zeros_like(obj), GRID, centre) is None


def test_a_truncated_mesh_is_an_error_naming_the_file(floor, tmp_path):
    canonical, _, _ = floor
    cut = tmp_path / "recon_mesh.ply"
    data = canonical.read_bytes()
    cut.write_bytes(data[: len(data) - 1000])
    with pytest.raises(ArtifactError, match=r"recon_mesh\.ply: the file ends inside its records \(\d+ bytes; its "
                                            r"header promises \d+ vertices and \d+ triangles"):
        read_windows(cut, [(0.0, 0.0, 40.0, 10.0)])


def test_a_face_that_is_no_triangle_is_an_error_naming_it(tmp_path):
    path = tmp_path / "quad.ply"
    header = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
              b"property float z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n")
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32).tobytes()
    path.write_bytes(header + verts + bytes([4]) + np.arange(4, dtype=np.uint32).tobytes()[:12])
    assert PlyLayout.of(path) is not None
    with pytest.raises(ArtifactError, match=r"quad\.ply: face 0 is not a triangle"):
        read_windows(path, [(0.0, 0.0, 1.0, 1.0)])


def test_a_missing_mesh_is_an_error_naming_it(tmp_path):
    sight = WindowedSight(tmp_path / "recon_mesh.ply", floor_z=0.0, camera_height_m=CAM_H, grid=GRID)
    with pytest.raises(MissingInputError, match=r"recon_mesh\.ply: no mesh file to cast line of sight on"):
        sight(np.array([[1.0, 1.0]]), (2.0, 2.0), [0.5], np.zeros((GRID.rows, GRID.cols), bool))
