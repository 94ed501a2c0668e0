"""ROS 2 MCAP reader: transports, pose sources, interpolation, ground truth, and malformed logs."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.ingest_params import IngestTopics
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.readers.ingest import ingest_path
from pipeline.scene_gt import Box, GTObject, GTRoom, GTScene
from tests.fixtures.raw_datasets import RawLog, make_recording, write_mcap, write_raw_log

QUIET = {"log": lambda m: None}


def _ingest(path, tmp_path, **params):
    out = tmp_path / "frames.zarr"
    summary = ingest_path(path, out, IngestParams(**params), **QUIET)
    return FrameStore(out), summary


def _write_c_log(path, rec, *, intrinsics=None, q_override=None):
    """``rec`` on /c/... topics frame by frame; ``intrinsics(i)`` / ``q_override(i)`` alter frame ``i``."""
    log = RawLog(path)
    for i in range(len(rec)):
        s = int(rec.stamps[i])
        log.image("/c/color/image_raw", s, rec.rgb[i], "rgb8")
        log.image("/c/depth/image_raw", s, rec.depth_mm[i], "16UC1")
        log.camera_info("/c/color/camera_info", s, intrinsics(i) if intrinsics else rec.intrinsics)
        log.pose("/c/pose", s, rec.poses[i], q_override=q_override(i) if q_override else None)
    log.close()


def _gt() -> GTScene:
    return GTScene(name="t", seed=3, wall_height_m=2.5,
                   rooms=[GTRoom(id="bedroom_1", type="bedroom", polygon=[(0, 0), (3, 0), (3, 3)])], walls=[],
                   objects=[GTObject(id=1, cls="chair", room="bedroom_1", parts=[Box(min=(0, 0, 0), max=(1, 1, 1))],
                                     color_name="red", color_rgb=(200, 0, 0), material="wood", size="big")])


@pytest.mark.parametrize("transport", ["raw", "compressed"])
@pytest.mark.parametrize("pose_kind", ["pose", "tf"])
def test_round_trip_exact(tmp_path, transport, pose_kind):
    rec = make_recording(12)
    fs, summary = _ingest(write_mcap(tmp_path / "log.mcap", rec, transport=transport, pose_kind=pose_kind), tmp_path)
    assert fs.n_frames == 12
    assert np.array_equal(fs.group["rgb"][:], rec.rgb)
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm)
    assert np.array_equal(fs.group["instance"][:], rec.instance)
    assert np.abs(fs.poses() - rec.poses).max() <= 1e-9
    assert summary["pose"]["frames_exact"] == 12
    if pose_kind == "tf":
        assert summary["pose"]["chain"] == ["map->odom", "odom->base_link", "base_link->camera_link",
                                            "camera_link->camera_color_optical_frame"]
        assert summary["pose"]["static_links"] == summary["pose"]["chain"][2:]


def test_faster_pose_stream_is_interpolated(tmp_path):
    rec = make_recording(12, fps=10.0)
    # poses at 30 Hz starting 1/4 period before the camera: every frame falls between two pose samples.
    path = write_mcap(tmp_path / "log.mcap", rec, pose_kind="tf", pose_rate_factor=3, pose_offset_ns=8_333_333,
                      pose_extra=0)
    fs, summary = _ingest(path, tmp_path)
    assert summary["matched_frames"] == 11  # the last frame lies after the last pose sample
    assert summary["unmatched"]["rgb"] == {"no_pose_coverage:outside_pose_range": 1}
    assert summary["unmatched_rgb_message_ranges"] == {"no_pose_coverage:outside_pose_range": [[11, 11]]}
    assert summary["pose"]["frames_interpolated"] == 11
    err = np.abs(fs.poses() - rec.poses[:11]).max()
    assert 1e-7 < err < 2e-3  # slerp/lerp between samples 33 ms apart on a smooth path
    # with a gap limit below the pose period nothing can be interpolated
    fs2 = tmp_path / "f2"
    fs2.mkdir()
    with pytest.raises(InputDataError, match="no frame could be matched.*11 no_pose_coverage:pose_gap_exceeds_max"):
        _ingest(path, fs2, max_pose_gap_s=0.02)


def test_ground_truth_and_metadata_are_carried(tmp_path):
    fs, _ = _ingest(write_mcap(tmp_path / "log.mcap", make_recording(3), gt=_gt()), tmp_path)
    assert isinstance(fs.ground_truth, GTScene) and fs.ground_truth == _gt()
    assert fs.attrs["provenance"]["mcap_metadata"] == {"zipon": {"test": "yes"}}


def test_depth_tolerance_and_unmatched_report(tmp_path):
    rec = make_recording(8)
    depth_stamps = rec.stamps + np.array([0, 5, 30, 0, 0, 0, 0, 0]) * 1_000_000  # frame 2: 30 ms off
    fs, s = _ingest(write_raw_log(tmp_path / "log.mcap", rec, depth_stamps=depth_stamps), tmp_path)
    assert s["matched_frames"] == 7
    assert s["unmatched"]["rgb"] == {"no_depth_within_tolerance": 1}
    assert s["unmatched"]["depth"] == {"no_rgb_within_tolerance": 1}
    assert s["unmatched_rgb_message_ranges"] == {"no_depth_within_tolerance": [[2, 2]]}
    assert s["max_matched_dt_s"]["depth"] == pytest.approx(0.005)
    assert s["messages"] == {"depth": 8, "rgb": 8, "world->camera": 8}
    assert np.array_equal(fs.stamps(), np.delete(rec.stamps, 2))


def test_bgr8_and_explicit_topics(tmp_path):
    rec = make_recording(3)
    path = write_raw_log(tmp_path / "log.mcap", rec, rgb_encoding="bgr8")
    topics = IngestTopics(rgb="/cam/color/image_raw", depth="/cam/depth/image_raw", pose="/cam/pose")
    fs, _ = _ingest(path, tmp_path, topics=topics)
    assert np.array_equal(fs.group["rgb"][:], rec.rgb)


def test_float_metre_depth(tmp_path):
    rec = make_recording(3)
    rec.depth_mm[0, 5, 5] = 0  # 0.0 m stays invalid
    fs, _ = _ingest(write_raw_log(tmp_path / "log.mcap", rec, depth_encoding="32FC1"), tmp_path)
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm)


def test_tf_world_frame_param(tmp_path):
    from pipeline.geometry import invert_pose
    from pipeline.ros2 import T_MAP_ODOM

    rec = make_recording(4)
    path = write_mcap(tmp_path / "log.mcap", rec, pose_kind="both")
    fs, s = _ingest(path, tmp_path, topics=IngestTopics(tf_world_frame="odom"))
    assert s["pose"]["chain"][0] == "odom->base_link"
    assert np.abs(fs.poses() - invert_pose(T_MAP_ODOM) @ rec.poses).max() < 1e-9


def test_depth_range_applied(tmp_path):
    rec = make_recording(3)
    fs, s = _ingest(write_mcap(tmp_path / "log.mcap", rec), tmp_path, depth_min_m=1.0, depth_max_m=5.0)
    d = rec.depth_mm
    assert np.array_equal(fs.group["depth"][:], np.where((d >= 1000) & (d <= 5000), d, 0))


# ----------------------------------------------------------------------------- malformed logs

def test_truncated_log(tmp_path):
    path = write_mcap(tmp_path / "log.mcap", make_recording(4))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputDataError, match=r"file .*log\.mcap: not a readable MCAP log \(truncated or corrupt"):
        _ingest(path, tmp_path)


def test_corrupt_chunk(tmp_path):
    path = write_mcap(tmp_path / "log.mcap", make_recording(4))
    data = bytearray(path.read_bytes())
    mid = len(data) // 3
    data[mid : mid + 64] = bytes(64)
    path.write_bytes(bytes(data))
    with pytest.raises(InputDataError, match=r"file .*log\.mcap: not a readable MCAP log \(truncated or corrupt"):
        _ingest(path, tmp_path)


def test_missing_depth_topic(tmp_path):
    path = write_raw_log(tmp_path / "log.mcap", make_recording(2), skip=("depth",))
    with pytest.raises(InputDataError, match=r"field ingest\.topics\.depth: no depth image topic; topics in the log: "
                                             r"/cam/color/camera_info \(sensor_msgs/msg/CameraInfo\), /cam/color/image_raw"):
        _ingest(path, tmp_path)


def test_missing_pose(tmp_path):
    path = write_raw_log(tmp_path / "log.mcap", make_recording(2), skip=("pose",))
    with pytest.raises(InputDataError, match=r"no camera pose in the log \(expected a geometry_msgs/PoseStamped topic or /tf"):
        _ingest(path, tmp_path)


def test_ambiguous_colour_topics(tmp_path):
    rec = make_recording(2)
    log = RawLog(tmp_path / "log.mcap")
    for topic in ("/left/color/image_raw", "/right/color/image_raw"):
        log.image(topic, int(rec.stamps[0]), rec.rgb[0], "rgb8")
    log.close()
    with pytest.raises(InputDataError, match=r"several colour image topics: /left/color/image_raw, /right/color/image_raw"
                                             r".*\(expected one colour image topic \(set ingest\.topics\.rgb\)\)"):
        _ingest(tmp_path / "log.mcap", tmp_path)


def test_unknown_encoding(tmp_path):
    path = write_raw_log(tmp_path / "log.mcap", make_recording(2), rgb_encoding="yuv422")
    with pytest.raises(InputDataError, match=r"topic /cam/color/image_raw; field encoding; frame 0: unknown image "
                                             r"encoding 'yuv422' \(expected one of \["):
        _ingest(path, tmp_path)


def test_image_size_differs_from_camera_info(tmp_path):
    rec = make_recording(2)
    from pipeline.geometry import Intrinsics

    path = write_raw_log(tmp_path / "log.mcap", rec, info_intr=Intrinsics.from_hfov(80, 60, 90))
    with pytest.raises(InputDataError, match=r"topic /cam/color/image_raw; field width/height; frame 0: image is 64x48 "
                                             r"\(expected 80x60 as in CameraInfo /cam/color/camera_info\)"):
        _ingest(path, tmp_path)


def test_camera_info_changes(tmp_path):
    from pipeline.geometry import Intrinsics

    rec = make_recording(3)
    _write_c_log(tmp_path / "log.mcap", rec, intrinsics=lambda i: rec.intrinsics if i < 2 else
                 Intrinsics(10, 10, 32, 24, 64, 48))
    with pytest.raises(InputDataError, match=r"topic /c/color/camera_info; field k/width/height; frame 2: CameraInfo "
                                             r"changed"):
        _ingest(tmp_path / "log.mcap", tmp_path)


@pytest.mark.parametrize("q, message", [
    ([np.nan, 0, 0, 1], r"topic /c/pose; field pose; frame 1: pose \[.*nan.*\] is not 7 finite numbers"),
    ([0, 0, 0.5, 0.5], r"topic /c/pose; field pose; frame 1: pose quaternion has norm 0\.707107: not a rotation"),
])
def test_bad_pose(tmp_path, q, message):
    rec = make_recording(3)
    _write_c_log(tmp_path / "log.mcap", rec, q_override=lambda i: q if i == 1 else None)
    with pytest.raises(InputDataError, match=message):
        _ingest(tmp_path / "log.mcap", tmp_path)


@pytest.mark.parametrize("shift, what", [(0, "duplicate"), (-50_000_000, "unsorted")])
def test_duplicate_or_unsorted_depth_stamps(tmp_path, shift, what):
    rec = make_recording(4)
    depth_stamps = rec.stamps.copy()
    depth_stamps[2] = depth_stamps[1] + shift
    path = write_raw_log(tmp_path / "log.mcap", rec, depth_stamps=depth_stamps)
    with pytest.raises(InputDataError, match=rf"topic /cam/depth/image_raw; field header\.stamp; frame 2: {what} stamp "
                                             r".* \(expected strictly increasing stamps\)"):
        _ingest(path, tmp_path)


def test_all_zero_depth(tmp_path):
    rec = make_recording(3)
    rec.depth_mm[:] = 0
    with pytest.raises(InputDataError, match=r"topic /camera/depth/image_raw; field depth: all 3 matched frames have "
                                             r"no valid depth"):
        _ingest(write_mcap(tmp_path / "log.mcap", rec), tmp_path)


def test_some_empty_depth_frames_are_reported(tmp_path):
    rec = make_recording(5)
    rec.depth_mm[[1, 2]] = 0
    _, s = _ingest(write_mcap(tmp_path / "log.mcap", rec), tmp_path)
    assert s["frames_without_valid_depth"] == {"count": 2, "ranges": [[1, 2]]}


def test_world_up_cannot_rotate_a_log_with_ground_truth(tmp_path):
    log = write_mcap(tmp_path / "log.mcap", make_recording(2), gt=_gt())
    with pytest.raises(InputDataError, match=r"field ingest\.world_up: ingest\.world_up '-y' would rotate a log that "
                                             r"carries ground truth"):
        _ingest(log, tmp_path, world_up="-y")
    assert not (tmp_path / "frames.zarr").exists()
    fs, _ = _ingest(log, tmp_path, world_up="+z")  # stating the log's own convention is fine
    assert fs.attrs["world_up"]["source_up"] == "+z"
