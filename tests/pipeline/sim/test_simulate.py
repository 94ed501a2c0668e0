"""Trajectory and end-to-end simulation: spin first, every room, exact frame count, noise, MCAP log."""

import json

import numpy as np
import pytest

from pipeline.config import SimulateParams
from pipeline.geometry import camera_yaw
from pipeline.sim import SceneRaycaster, SimulatedRecording, free_space, simulate_scene

SMALL = dict(frames=30, width=80, height=60, render_block_frames=7)


@pytest.fixture(scope="module")
def rec():
    return SimulatedRecording("demo", SimulateParams(**SMALL))


def test_trajectory_spins_first_then_enters_every_room(rec):
    s = rec.states
    assert np.allclose(s[:25, :2], s[0, :2])  # 24 turns in place first
    np.testing.assert_allclose(np.diff(s[:25, 2]), np.deg2rad(15.0))
    moves = np.hypot(*np.diff(s[:, :2], axis=0).T)
    turns = np.abs(np.diff(s[:, 2]))
    assert ((moves > 0) != (turns > 0)).all()  # each action either turns or steps
    assert moves.max() <= 0.25 + 1e-9 and np.allclose(turns[turns > 0], np.deg2rad(15.0))
    assert set(rec.visited) == {r.id for r in rec.gt.rooms}
    fs = free_space(rec.gt, 0.1)
    assert fs.is_navigable(s[:, :2]).all()  # never inside furniture or walls
    rooms_entered = {int(fs.room_of_cell[tuple(fs.grid.world_to_cell(p))]) for p in s[:, :2]}
    assert rooms_entered >= set(range(len(rec.gt.rooms)))


def test_frames_exact_and_stamped_at_fps(rec):
    assert rec.frame_T.shape == (30, 4, 4) and len(rec.frame_ns) == 30
    np.testing.assert_array_equal(np.diff(rec.frame_ns), 100_000_000)
    assert rec.pose_ns[0] <= rec.frame_ns[0] and rec.pose_ns[-1] >= rec.frame_ns[-1]
    assert np.diff(rec.pose_ns).max() <= 1e9 / 30 + 1
    np.testing.assert_allclose(rec.frame_T[:, 2, 3], 0.88)
    demo = SimulatedRecording("demo", SimulateParams(frames=240))  # planning only (no rendering)
    yaw = np.unwrap(camera_yaw(demo.frame_T))
    start = np.flatnonzero(np.hypot(*(demo.frame_T[:, :2, 3] - demo.frame_T[0, :2, 3]).T) > 1e-9)[0]
    top = int(np.argmax(yaw[:start]))
    assert yaw[top] - yaw[0] >= np.deg2rad(330)  # the opening spin, in place, is visible in the frames
    assert np.all(np.diff(yaw[:top + 1]) > 0)


def _render_all(rec):
    r = SceneRaycaster(rec.gt, rec.intrinsics)
    blocks = list(rec.blocks(r))
    assert [b[0] for b in blocks] == [0, 7, 14, 21, 28]
    return [np.concatenate([b[k] for b in blocks]) for k in (1, 2, 3)]


def test_noise_changes_only_what_it_should(rec):
    rgb, depth, inst = _render_all(rec)
    noisy_depth = SimulatedRecording("demo", SimulateParams(**SMALL, depth_noise_m=0.01))
    rgb2, depth2, inst2 = _render_all(noisy_depth)
    assert np.array_equal(rgb, rgb2) and np.array_equal(inst, inst2)
    np.testing.assert_array_equal(noisy_depth.recorded_pose_T, rec.recorded_pose_T)
    diff = depth2.astype(float) - depth.astype(float)
    valid = (depth > 0) & (depth2 > 0)
    assert 0.5 < np.abs(diff[valid]).mean() < 60  # millimetres, grows with depth^2
    jitter = SimulatedRecording("demo", SimulateParams(**SMALL, pose_jitter_m=0.02, pose_jitter_deg=1.0))
    np.testing.assert_array_equal(jitter.frame_T, rec.frame_T)  # true poses (images) unchanged
    err = np.hypot(*(jitter.recorded_pose_T[:, :2, 3] - rec.true_pose_T[:, :2, 3]).T)
    assert 0.01 < err.mean() < 0.04
    np.testing.assert_allclose(jitter.recorded_pose_T[:, 2, 3], rec.true_pose_T[:, 2, 3])
    np.testing.assert_array_equal(rec.recorded_pose_T, rec.true_pose_T)


def test_simulate_scene_writes_deterministic_mcap(tmp_path):
    from mcap.reader import make_reader

    params = SimulateParams(**{**SMALL, "frames": 12})
    a = simulate_scene("demo", params, tmp_path / "a.mcap")
    simulate_scene("demo", params, tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    assert a["frames"] == 12 and a["classes"] >= 15 and a["rooms_visited"] == a["rooms"]
    with open(tmp_path / "a.mcap", "rb") as f:
        reader = make_reader(f)
        counts = {}
        for _, channel, _ in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        attachments = list(reader.iter_attachments())
    assert counts["/camera/color/image_raw"] == counts["/camera/depth/image_raw"] == 12
    assert counts["/camera/instance/image_raw"] == 12 and counts["/camera/pose"] == a["poses"]
    gt = json.loads(attachments[0].data)
    assert attachments[0].name == "ground_truth.json" and len(gt["objects"]) == a["objects"]


def test_a_house_log_carries_its_floors_stairs_and_building(tmp_path):
    from mcap.reader import make_reader

    from pipeline.config import BuildingParams
    from pipeline.scene_gt import GTScene
    from pipeline.sim import draw_scene_topdown

    house = BuildingParams(kind="house", stories=2)
    s = simulate_scene("house_t", SimulateParams(frames=24, width=32, height=24), tmp_path / "h.mcap", building=house)
    assert s["floors"] == 2 and s["stairs"] == 1 and sum(s["frames_per_floor"]) == 24 and min(s["frames_per_floor"]) > 0
    assert s["building"] == "house" and s["rooms_visited"] == s["rooms"]
    with open(tmp_path / "h.mcap", "rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        gt = GTScene.read(json.loads(next(reader.iter_attachments()).data), "h.mcap")
    assert json.loads(next(iter(meta.values()))["building"])["kind"] == "house"
    assert [f.id for f in gt.floors] == [0, 1] and gt.stairs[0].upper == 1
    # the plan of each floor: the flight drawn in brown on the lower floor, the opening in grey on the upper one
    lower, upper = (draw_scene_topdown(gt, floor=k, px_per_m=20) for k in (0, 1))
    brown, grey = np.array([150, 108, 72]), np.array([96, 96, 120])
    assert (lower == brown).all(-1).sum() > 100 and not (upper == brown).all(-1).any()
    assert (upper == grey).all(-1).sum() > 100 and not (lower == grey).all(-1).any()
