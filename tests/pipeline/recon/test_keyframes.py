"""Keyframes: the motion and novel-pixel tests on poses and depths whose answer is known, and a reconstruction that
fuses only its keyframes while keeping and recording every frame."""

import numpy as np
import pytest

from pipeline.config import GridParams, ReconstructParams
from pipeline.geometry import Intrinsics, camera_pose_from_base
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from pipeline.recon.keyframes import motion, novel_fraction, select_by_motion
from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames, write_frames

WALL = Intrinsics(32.0, 32.0, 32.0, 24.0, 64, 48)  # a 64x48 camera looking at a wall 2 m ahead


def _walk(step_m: float = 0.0, turn_deg: float = 0.0, n: int = 13) -> np.ndarray:
    return np.stack([camera_pose_from_base(1.0 + k * step_m, 2.0, np.radians(k * turn_deg), 0.88) for k in range(n)])


def test_motion_is_the_distance_and_the_angle_between_two_poses():
    a, b = _walk(step_m=0.3, turn_deg=30.0, n=2)
    translation, rotation = motion(a, b)
    assert translation == pytest.approx(0.3) and rotation == pytest.approx(30.0)


def test_a_step_past_the_translation_threshold_makes_a_keyframe():
    # 3 cm a frame, 10 cm threshold: 9 cm is not enough, 12 cm is; the next keyframe counts from the last one
    assert np.flatnonzero(select_by_motion(_walk(step_m=0.03), 0.1, 10.0)).tolist() == [0, 4, 8, 12]


def test_a_turn_past_the_rotation_threshold_makes_a_keyframe():
    assert np.flatnonzero(select_by_motion(_walk(turn_deg=4.0), 0.1, 10.0)).tolist() == [0, 3, 6, 9, 12]
    assert select_by_motion(_walk(n=5), 0.1, 10.0).tolist() == [True, False, False, False, False]


def test_novel_pixels_of_a_wall_seen_from_the_side_and_behind_an_occluder():
    depth = np.full((48, 64), 2000, dtype=np.uint16)
    T = np.eye(4)
    assert novel_fraction(depth, T, depth, T, WALL, 1, 0.05) == 0.0
    moved = T.copy()
    moved[0, 3] = 2.0  # 2 m sideways at 2 m depth with fx 32: the wall moves by 32 px, half the image
    assert novel_fraction(depth, moved, depth, T, WALL, 1, 0.05) == pytest.approx(0.5, abs=0.02)
    assert novel_fraction(depth, T, np.zeros_like(depth), T, WALL, 1, 0.05) == 1.0  # the keyframe saw no depth
    nearer = depth.copy()
    nearer[:, :16] = 1000  # an object the keyframe did not have in front of the wall: a quarter of the pixels
    assert novel_fraction(nearer, T, depth, T, WALL, 2, 0.05) == pytest.approx(0.25)


@pytest.fixture(scope="module")
def repeated_room(tmp_path_factory):
    """The box room's 12 views, each recorded three times in a row (a robot standing still): 36 frames."""
    intr = Intrinsics.from_hfov(96, 72, 90.0)
    gt = box_room_gt()
    poses = np.repeat(box_room_poses(12), 3, axis=0)
    rgb, depth, _ = render_frames(gt, poses, intr)
    return write_frames(tmp_path_factory.mktemp("kf") / "frames.zarr", gt, rgb, depth, poses, intr), poses


def test_a_reconstruction_fuses_its_keyframes_and_records_them(repeated_room, tmp_path):
    frames, poses = repeated_room
    p = ReconstructParams(voxel_size_m=0.05, min_weight=1.0, keyframes=True)
    out = tmp_path / "recon.zarr"
    summary = reconstruct(frames, out, tmp_path / "mesh.ply", tmp_path / "points.ply", p, GridParams(rows=160, cols=200))
    expected = np.zeros(36, dtype=bool)
    expected[::3] = True  # each view's first recording: its repeats neither move nor see anything new
    recon = Recon(out)
    assert recon.fused.tolist() == expected.tolist()
    assert np.allclose(recon.poses, poses)  # every frame keeps its pose: the maps may still read them all
    kf = recon.attrs["keyframes"]
    assert (kf["enabled"], kf["keyframes"], kf["frames_with_depth"]) == (True, 12, 36)
    assert sum(kf["reasons"].values()) == 12 and kf["reasons"]["first"] == 1
    assert summary["keyframes"] == kf and summary["frames_fused"] == 12


def test_without_keyframes_every_frame_is_fused(repeated_room, tmp_path):
    frames, _ = repeated_room
    p = ReconstructParams(voxel_size_m=0.05, min_weight=1.0)
    summary = reconstruct(frames, tmp_path / "recon.zarr", tmp_path / "mesh.ply", tmp_path / "points.ply", p,
                          GridParams(rows=160, cols=200))
    assert summary["frames_fused"] == 36 and summary["keyframes"] == {"enabled": False}
    assert Recon(tmp_path / "recon.zarr").fused.all()
