"""ROS 2 message definitions, the log writer, and the numpy CDR image parser."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pipeline.geometry import pose_from_tq
from pipeline.ros2 import (TOPICS, Ros2LogWriter, compressed_image_to_array, parse_compressed_cdr, parse_image_cdr,
                           raw_image_to_array)
from tests.fixtures.raw_datasets import make_recording


def _messages(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        out = {}
        for schema, channel, msg, dec in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((schema.name, msg, dec))
        return out


def test_raw_log_topics_and_fields(tmp_path):
    rec = make_recording(3)
    with Ros2LogWriter(tmp_path / "l.mcap", intrinsics=rec.intrinsics, pose_topic_kind="both") as w:
        for i in range(3):
            w.write_frame(int(rec.stamps[i]), rec.rgb[i], rec.depth_mm[i], rec.instance[i])
            w.write_pose(int(rec.stamps[i]), rec.poses[i])
    msgs = _messages(tmp_path / "l.mcap")
    assert set(msgs) == {TOPICS[k] for k in ("rgb", "depth", "instance", "camera_info", "pose", "tf", "tf_static")}
    schema, msg, img = msgs[TOPICS["depth"]][1]
    assert schema == "sensor_msgs/msg/Image" and img.encoding == "16UC1" and (img.height, img.width) == (48, 64)
    assert msg.log_time == rec.stamps[1] == img.header.stamp.sec * 10**9 + img.header.stamp.nanosec
    assert np.array_equal(np.frombuffer(img.data, np.uint16).reshape(48, 64), rec.depth_mm[1])
    info = msgs[TOPICS["camera_info"]][0][2]
    assert np.allclose(np.reshape(info.k, (3, 3)), rec.intrinsics.K) and info.width == 64
    # the numpy parser agrees with mcap_ros2's generic decoder
    fast = parse_image_cdr(msgs[TOPICS["rgb"]][2][1].data)
    assert fast["encoding"] == "rgb8" and fast["stamp_ns"] == rec.stamps[2]
    assert fast["frame_id"] == "camera_color_optical_frame"
    assert np.array_equal(raw_image_to_array(fast, where={}), rec.rgb[2])
    # /tf_static + /tf compose to the written camera pose
    frames = {}
    for name in ("tf_static", "tf"):
        for tr in msgs[TOPICS[name]][-1][2].transforms:
            t, q = tr.transform.translation, tr.transform.rotation
            frames[tr.child_frame_id] = (tr.header.frame_id, pose_from_tq(np.array([t.x, t.y, t.z]),
                                                                          np.array([q.x, q.y, q.z, q.w])))
    T, f = np.eye(4), "camera_color_optical_frame"
    while f in frames:
        parent, P = frames[f]
        T, f = P @ T, parent
    assert f == "map" and np.abs(T - rec.poses[2]).max() < 1e-12


def test_compressed_transport(tmp_path):
    rec = make_recording(2)
    with Ros2LogWriter(tmp_path / "l.mcap", intrinsics=rec.intrinsics, image_transport="compressed",
                       with_instance=False) as w:
        w.write_frame(int(rec.stamps[0]), rec.rgb[0], rec.depth_mm[0])
    msgs = _messages(tmp_path / "l.mcap")
    assert TOPICS["instance"] + "/compressed" not in msgs
    _, m, dec = msgs[TOPICS["depth"] + "/compressedDepth"][0]
    assert dec.format == "16UC1; compressedDepth png"
    assert struct.unpack("<iff", dec.data[:12]) == (0, 0.0, 0.0) and dec.data[12:16] == b"\x89PNG"
    parsed = parse_compressed_cdr(m.data)
    assert np.array_equal(compressed_image_to_array(parsed, where={}), rec.depth_mm[0])
    _, m, dec = msgs[TOPICS["rgb"] + "/compressed"][0]
    assert dec.format == "rgb8; png compressed bgr8"
    assert np.array_equal(compressed_image_to_array(parse_compressed_cdr(m.data), where={}), rec.rgb[0])


def test_writer_rejects_wrong_arrays(tmp_path):
    rec = make_recording(1)
    with Ros2LogWriter(tmp_path / "l.mcap", intrinsics=rec.intrinsics) as w:
        with pytest.raises(ValueError, match=r"depth_mm is float64\(48, 64\), expected uint16\(48, 64\)"):
            w.write_frame(0, rec.rgb[0], rec.depth_mm[0].astype(float), rec.instance[0])
        with pytest.raises(ValueError, match="with_instance=True"):
            w.write_frame(0, rec.rgb[0], rec.depth_mm[0])


@pytest.mark.parametrize("encoding, arr", [
    ("bgra8", np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4)),
    ("mono8", np.arange(6, dtype=np.uint8).reshape(2, 3)),
    ("32FC1", np.array([[0.5, np.nan, 2.0], [1.0, 0.0, 3.25]], dtype=np.float32)),
])
def test_raw_encodings(encoding, arr):
    msg = {"encoding": encoding, "height": 2, "width": 3, "step": arr.strides[0], "is_bigendian": 0,
           "data": arr.tobytes()}
    out = raw_image_to_array(msg, where={})
    if encoding == "bgra8":
        assert np.array_equal(out, arr[..., [2, 1, 0]])
    elif encoding == "mono8":
        assert out.shape == (2, 3, 3) and np.array_equal(out[..., 1], arr)
    else:
        assert np.array_equal(out, arr, equal_nan=True)
