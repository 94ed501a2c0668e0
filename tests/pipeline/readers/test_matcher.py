"""The shared matcher on synthetic sample streams: accounting, bounded memory, stalled streams."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.geometry import Intrinsics, pose_from_tq
from pipeline.readers.base import DEPTH, POSE, RGB, PoseLink, Sample, SourceInfo
from pipeline.readers.matcher import FrameMatcher

MS = 1_000_000


def _info(static=None) -> SourceInfo:
    chain = [PoseLink("world", "body")] + ([PoseLink("body", "camera", static)] if static is not None else [])
    return SourceInfo(intrinsics=Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2), has_instance=False, pose_chain=chain,
                      where={RGB: "c", DEPTH: "d", "world->body": "p"})


def _pose(t_ns: int) -> np.ndarray:
    t = t_ns * 1e-9
    return pose_from_tq(np.array([t, 2 * t, 0.0]), np.array([0, 0, np.sin(t / 2), np.cos(t / 2)]))


def _stream(n_frames, *, fps=30.0, pose_hz=100.0, depth_until=None, depth_every=1, depth_offset_ms=0.0):
    """Samples in time order (as a recorder writes them): colour, depth, poses."""
    events = []
    for i in range(n_frames):
        t = int(round(i * 1e9 / fps))
        events.append((t, Sample(RGB, t, i, np.full((2, 2, 3), i % 256, np.uint8))))
    for i in range(0, n_frames * depth_every):
        t = int(round(i * 1e9 / (fps * depth_every) + depth_offset_ms * MS))
        if depth_until is None or t < depth_until:
            events.append((t, Sample(DEPTH, t, i, np.full((2, 2), 1000, np.uint16))))
    n_pose = int(n_frames / fps * pose_hz) + 2
    for k in range(n_pose):
        t = int(round(k * 1e9 / pose_hz))
        events.append((t, Sample(POSE, t, k, _pose(t), key="world->body")))
    events.sort(key=lambda e: (e[0], e[1].stream))
    return [s for _, s in events]


def _run(matcher, samples):
    peak = {"pending": 0, "poses": 0}
    frames = []

    def watch():
        for s in samples:
            yield s
            peak["pending"] = max(peak["pending"], sum(len(q) for q in matcher.pending.values()))
            peak["poses"] = max(peak["poses"], max(len(t.stamps) for t in matcher.tracks.values()))

    for block in matcher.blocks(watch()):
        frames.append(block)
    return frames, peak


def test_memory_is_bounded_by_the_window_not_the_log():
    peaks = []
    for n in (300, 3000):
        m = FrameMatcher(_info(), IngestParams(block_frames=8), "synthetic")
        blocks, peak = _run(m, _stream(n))
        assert sum(len(b) for b in blocks) == n
        peaks.append(peak)
    assert peaks[0] == peaks[1]
    # colour waits for depth up to stamp + tolerance: a few samples of each stream, at any log length
    assert peaks[1]["pending"] <= 4 and peaks[1]["poses"] <= 12


def test_interpolated_pose_and_static_link():
    static = pose_from_tq(np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, 0.0, 1.0]))
    m = FrameMatcher(_info(static), IngestParams(block_frames=64), "synthetic")
    blocks, _ = _run(m, _stream(30))
    T = np.concatenate([b.T_world_camera for b in blocks])
    stamps = np.concatenate([b.stamp_ns for b in blocks])
    expect = np.stack([_pose(int(t)) @ static for t in stamps])
    # linear translation is exact for this linear path; the rotation is a constant-rate yaw, so slerp is exact
    assert np.abs(T - expect).max() < 1e-12
    s = m.summary()
    assert s["pose"]["frames_exact"] + s["pose"]["frames_interpolated"] == 30
    assert s["pose"]["frames_interpolated"] == 20  # 30 Hz vs 100 Hz: every third frame hits a pose stamp


def test_stalled_depth_stream_is_reported_not_buffered():
    m = FrameMatcher(_info(), IngestParams(block_frames=8, max_stream_lag_s=0.5), "synthetic")
    blocks, peak = _run(m, _stream(600, depth_until=5 * 10**9))  # depth stops after 5 s of 20 s
    s = m.summary()
    assert s["matched_frames"] == sum(len(b) for b in blocks) == 150
    assert s["unmatched"]["rgb"] == {"no_depth_within_tolerance": 450}
    assert s["unmatched_rgb_message_ranges"] == {"no_depth_within_tolerance": [[150, 599]]}
    assert peak["pending"] <= 0.5 * 30 + 3  # the lag window, not the 450 waiting frames


@pytest.mark.parametrize("depth_every, offset", [(2, 0.0), (1, 25.0)])
def test_every_message_is_accounted_for(depth_every, offset):
    m = FrameMatcher(_info(), IngestParams(block_frames=8), "synthetic")
    _run(m, _stream(90, fps=10.0, depth_every=depth_every, depth_offset_ms=offset))
    s = m.summary()
    for stream in (RGB, DEPTH):
        assert s["messages"][stream] == s["matched_frames"] + sum(s["unmatched"][stream].values())
    if depth_every == 2:
        assert s["matched_frames"] == 90
        # the in-between depth frames are 50 ms from any colour frame
        assert s["unmatched"][DEPTH] == {"no_rgb_within_tolerance": 90}
    else:  # 25 ms late depth is outside the 20 ms tolerance (and 75 ms before the next colour frame)
        assert s["matched_frames"] == 0
