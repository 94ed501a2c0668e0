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


# ----------------------------------------------------------------------------- world up, nearest rigid

def test_R_zup_from_up_axes():
    from pipeline.geometry import R_ZUP_FROM_HABITAT, WORLD_UP_AXES, R_zup_from_up

    for name, up in WORLD_UP_AXES.items():
        R = R_zup_from_up(name)
        assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        assert np.allclose(R @ np.array(up), [0, 0, 1])
        assert set(np.abs(R).ravel().tolist()) == {0.0, 1.0}  # a signed permutation: nothing else moves
    assert np.array_equal(R_zup_from_up("-y") @ [1.0, 2.0, 3.0], [1.0, 3.0, -2.0])  # 7-Scenes: (x, y, z) -> (x, z, -y)
    assert np.array_equal(R_zup_from_up("+y"), R_ZUP_FROM_HABITAT)
    assert np.array_equal(R_zup_from_up("+z"), np.eye(3))


def test_R_zup_from_up_vector_tilts_least():
    from pipeline.geometry import R_zup_from_up

    tilt = np.radians(3.0)
    up = np.array([0.0, -np.cos(tilt), np.sin(tilt)])  # y down, tilted 3 deg toward +z
    R = R_zup_from_up(up)
    assert np.allclose(R @ up, [0, 0, 1]) and np.linalg.det(R) == pytest.approx(1.0)
    # the smallest extra rotation after the axis permutation: 3 degrees
    extra = R @ R_zup_from_up("-y").T
    assert np.degrees(np.arccos((np.trace(extra) - 1) / 2)) == pytest.approx(3.0)


def test_rotate_world_and_nearest_rigid():
    from pipeline.errors import InputDataError
    from pipeline.geometry import R_zup_from_up, nearest_rigid, rigid_error, rotate_world

    T = camera_pose_from_base(1.0, 2.0, 0.3, 0.88)
    R = R_zup_from_up("-y").T  # z-up -> y-down
    back = rotate_world(R_zup_from_up("-y"), rotate_world(R, T))
    assert np.allclose(back, T, atol=1e-15)
    skewed = T.copy()
    skewed[:3, :3] += 2e-4 * np.array([[1, -1, 0.5], [0, 1, -1], [1, 0, -0.5]])
    fixed = nearest_rigid(skewed, tol=1e-3)
    assert rigid_error(fixed) < 1e-12 and np.abs(fixed - T).max() < 1e-3 and np.array_equal(fixed[:3, 3], T[:3, 3])
    with pytest.raises(InputDataError, match=r"file p\.txt; frame 4: pose is not rigid"):
        nearest_rigid(skewed, tol=1e-5, path="p.txt", frame=4)


def test_a_grid_holds_a_point_on_a_true_cell_of_a_mask_and_nothing_off_it():
    g = GridSpec(4, 5, 0.5, (0.0, 2.0))  # x 0..2.5 east, y 2..0 south
    mask = np.zeros((4, 5), bool)
    mask[1, 3] = True  # x 1.5..2.0, y 1.0..1.5
    assert g.holds(mask, (1.7, 1.2)) and g.holds(mask, (1.7, 1.2, 0.3))  # a pose's yaw is ignored
    assert not g.holds(mask, (0.2, 1.2)) and not g.holds(mask, (-1.0, 1.2)) and not g.holds(mask, (1.7, 9.0))
