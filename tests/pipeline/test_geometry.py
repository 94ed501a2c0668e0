import numpy as np
import pytest

from pipeline.errors import InputDataError
from pipeline.geometry import (
    GridSpec, Intrinsics, backproject, camera_pose_from_base, camera_yaw, check_rigid, habitat_to_world,
    interpolate_poses, invert_pose, pose_from_tq, pose_to_tq,
)


def test_pose_roundtrip_and_inverse():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = rng.normal(size=(5, 3))
    T = pose_from_tq(t, q)
    t2, q2 = pose_to_tq(T)
    assert np.allclose(t2, t)
    assert np.allclose(np.abs(np.sum(q2 * q, axis=1)), 1.0)
    assert np.allclose(T @ invert_pose(T), np.eye(4), atol=1e-12)


def test_check_rigid_names_the_frame():
    T = np.repeat(np.eye(4)[None], 4, axis=0)
    T[2, 0, 0] = np.nan
    with pytest.raises(InputDataError, match="topic /pose; frame 12: pose contains NaN"):
        check_rigid(T, topic="/pose", first_frame=10)
    T[2] = np.eye(4)
    T[3, :3, :3] *= 1.1
    with pytest.raises(InputDataError, match=r"frame 3: pose is not rigid"):
        check_rigid(T)


def test_interpolation_is_linear_and_slerp():
    a = camera_pose_from_base(0, 0, 0.0, 1.0)
    b = camera_pose_from_base(2, 0, np.pi / 2, 1.0)
    mid = interpolate_poses(np.array([0, 2_000_000_000]), np.stack([a, b]), np.array([1_000_000_000]))[0]
    assert np.allclose(mid[:3, 3], [1, 0, 1])
    assert np.isclose(camera_yaw(mid), np.pi / 4)


def test_camera_looks_along_yaw_and_y_is_down():
    T = camera_pose_from_base(1, 2, np.pi / 2, 0.88)
    assert np.allclose(T[:3, 2], [0, 1, 0], atol=1e-12)  # optical z forward = +y world
    assert np.allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # image down = world down
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)
    check_rigid(T[None])


def test_habitat_base_pose_converts_to_zup_camera():
    # Habitat base at (1, 0, -2) (y up) with identity rotation looks along -z_hab = +y in zipon's world.
    T_hab = np.eye(4)
    T_hab[:3, 3] = [1.0, 0.0, -2.0]
    T = habitat_to_world(T_hab, 0.88)
    assert np.allclose(T[:3, 3], [1.0, 2.0, 0.88])
    assert np.allclose(T[:3, 2], [0, 1, 0], atol=1e-12)
    assert np.allclose(T[:3, 1], [0, 0, -1], atol=1e-12)


def test_grid_world_cell_roundtrip_and_north_up():
    g = GridSpec.centered((1.0, -2.0), rows=600, cols=600, cell_size_m=0.05)
    xy = np.array([[1.0, -2.0], [1.0 + 0.05 * 10, -2.0], [1.0, -2.0 + 0.05 * 10]])
    rc = g.world_to_cell(xy)
    assert tuple(rc[0]) == (300, 300)
    assert rc[1, 1] == rc[0, 1] + 10 and rc[1, 0] == rc[0, 0]  # east -> col grows
    assert rc[2, 0] == rc[0, 0] - 10  # north -> row shrinks (north-up)
    assert np.allclose(g.world_to_cell(g.cell_to_world(rc)), rc)
    assert GridSpec.from_attrs(g.to_attrs()) == g


def test_backprojection_matches_pinhole():
    intr = Intrinsics.from_hfov(640, 480, 90.0)
    assert intr.fx == pytest.approx(320.0)
    depth = np.full((480, 640), 2.0, np.float32)
    pts = backproject(depth, intr)
    assert np.allclose(pts[240, 320], [0, 0, 2])
    assert np.allclose(pts[240, 0], [-2.0, 0, 2])  # 45 degrees at the left edge
    half = intr.scaled(320, 240)
    assert half.fx == pytest.approx(160.0) and half.cx == pytest.approx(159.75)
