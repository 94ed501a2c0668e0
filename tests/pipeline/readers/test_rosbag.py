"""ROS 1 .bag and ROS 2 .db3 / .mcap bags written with rosbags' own writers, read through rosbags with the
MCAP reader's topic detection, tf and matching."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.readers import detect_format
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import BAG_KINDS, cli_ingest, make_recording, write_bag

QUIET = {"log": lambda m: None}


@pytest.mark.parametrize("kind", sorted(BAG_KINDS))
@pytest.mark.parametrize("pose_kind", ["pose", "tf"])
def test_round_trip_exact(tmp_path, kind, pose_kind):
    rec = make_recording(6)
    bag = write_bag(tmp_path, rec, kind, pose_kind=pose_kind)
    summary = ingest_path(bag, tmp_path / "f.zarr", IngestParams(block_frames=4), fmt="rosbag", **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert summary["matched_frames"] == fs.n_frames == 6
    assert np.array_equal(fs.group["rgb"][:], rec.rgb)
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm)
    assert np.array_equal(fs.group["instance"][:], rec.instance)
    assert np.array_equal(fs.stamps(), rec.stamps)
    assert np.abs(fs.poses() - rec.poses).max() <= 1e-9
    prov = fs.attrs["provenance"]
    assert prov["format"] == "rosbag" and prov["bag"]["reader"] == "rosbags"
    assert prov["bag"]["container"] == ("ROS 1 bag" if kind == "ros1" else "ROS 2 bag")
    if pose_kind == "tf":
        assert summary["pose"]["chain"] == ["map->base_link", "base_link->camera_color_optical_frame"]


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_compressed_transport(tmp_path, kind):
    rec = make_recording(3)
    bag = write_bag(tmp_path, rec, kind, transport="compressed")
    ingest_path(bag, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert np.array_equal(fs.group["rgb"][:], rec.rgb) and np.array_equal(fs.group["depth"][:], rec.depth_mm)
    assert np.array_equal(fs.group["instance"][:], rec.instance)
    assert fs.attrs["provenance"]["topics"]["rgb"] == "/camera/color/image_raw/compressed"


def test_ros2_bag_without_message_definitions(tmp_path):
    """Bags recorded before ROS 2 Iron carry no message definitions (an empty message_definitions table)."""
    import sqlite3

    rec = make_recording(3)
    bag = write_bag(tmp_path, rec, "ros2")
    con = sqlite3.connect(next(bag.glob("*.db3")))
    con.execute("DELETE FROM message_definitions")
    con.commit()
    con.close()
    ingest_path(bag, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm) and np.abs(fs.poses() - rec.poses).max() < 1e-9
    assert fs.attrs["provenance"]["bag"]["message_definitions"] == "rosbags' ROS 2 Humble type store"


def test_detection(tmp_path):
    rec = make_recording(2)
    assert detect_format(write_bag(tmp_path, rec, "ros1")) == "rosbag"
    sqlite = write_bag(tmp_path, rec, "ros2")
    assert detect_format(sqlite) == "rosbag"  # rosbag2 folder with a .db3
    assert detect_format(next(sqlite.glob("*.db3"))) == "rosbag"
    assert detect_format(write_bag(tmp_path, rec, "ros2-mcap")) == "mcap"  # the faster reader for .mcap


def test_truncated_bag_is_a_clear_error(tmp_path, capsys):
    bag = write_bag(tmp_path, make_recording(3), "ros1")
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputDataError, match=r"file .*log\.bag: not a readable ROS bag"):
        ingest_path(bag, tmp_path / "f.zarr", IngestParams(), **QUIET)
    assert not (tmp_path / "f.zarr").exists()
    code, err = cli_ingest(tmp_path, bag, "b", capsys=capsys)
    assert code == 1 and "log.bag: not a readable ROS bag" in err
    assert not (tmp_path / "data" / "artifacts" / "b" / "frames.zarr").exists()


def test_missing_depth_topic_lists_the_bag_topics(tmp_path):
    from tests.fixtures.raw_datasets import BagLog

    rec = make_recording(2)
    bag = BagLog(tmp_path / "x.bag", "ros1")
    for i in range(2):
        bag.image("/camera/color/image_raw", int(rec.stamps[i]), rec.rgb[i], "rgb8")
        bag.camera_info("/camera/color/camera_info", int(rec.stamps[i]), rec.intrinsics)
    bag.close()
    with pytest.raises(InputDataError, match=r"field ingest\.topics\.depth: no depth image topic; topics in the "
                                             r"log: /camera/color/camera_info \(sensor_msgs/msg/CameraInfo\)"):
        ingest_path(tmp_path / "x.bag", tmp_path / "f.zarr", IngestParams(), **QUIET)
