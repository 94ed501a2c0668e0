"""Depth on its own camera (RealSense-style) is registered into the colour camera, or refused naming both topics."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import Intrinsics
from pipeline.readers.ingest import ingest_path
from pipeline.readers.registration import DepthRegistration
from tests.fixtures.raw_datasets import cli_ingest, write_realsense_mcap

QUIET = {"log": lambda m: None}


def test_plane_registers_exactly():
    """A fronto-parallel plane 2 m away seen by a narrower depth camera 10 cm to the left: z is kept, pixels move."""
    d, c = Intrinsics(100.0, 100.0, 31.5, 23.5, 64, 48), Intrinsics(40.0, 40.0, 15.5, 11.5, 32, 24)
    T = np.eye(4)
    T[0, 3] = -0.1  # a depth-camera point lies 0.1 m further left in the colour camera
    out = DepthRegistration(d, c, T)(np.full((48, 64), 2000, np.uint16))
    assert out.shape == (24, 32) and out.dtype == np.uint16
    # depth columns 0..63 -> x = (u - 31.5) / 100 * 2 - 0.1 -> colour u = 20 x + 15.5 in [0.9, 26.1] -> 1..26;
    # rows: 20 (v - 23.5) / 50 + 11.5 in [2.1, 20.9] -> 2..21
    inside = np.zeros((24, 32), bool)
    inside[2:22, 1:27] = True
    assert (out[inside] == 2000).all() and (out[~inside] == 0).all()
    metres = DepthRegistration(d, c, T)(np.full((48, 64), 2.0, np.float32))
    assert metres.dtype == np.float32 and np.abs(metres[inside] - 2.0).max() < 1e-6 and np.isnan(metres[~inside]).all()


def test_same_camera_is_the_identity():
    k = Intrinsics(30.0, 30.0, 15.5, 11.5, 32, 24)
    depth = np.random.default_rng(0).integers(0, 5000, (24, 32)).astype(np.uint16)
    assert np.array_equal(DepthRegistration(k, k, np.eye(4))(depth), depth)


def test_z_buffer_keeps_the_nearest_surface():
    d = c = Intrinsics(10.0, 10.0, 1.5, 1.5, 4, 4)
    depth = np.full((4, 4), 3000, np.uint16)
    depth[:, 1] = 1000  # a near column; shifted by the baseline it lands on the far column next to it
    T = np.eye(4)
    T[0, 3] = 0.1  # at 1 m: +1 px; at 3 m: +1/3 px (rounds to the same column)
    out = DepthRegistration(d, c, T)(depth)
    assert (out[:, 2] == 1000).all()  # near and far land on column 2: the near one wins


def test_realsense_mcap_is_registered(tmp_path):
    log, poses, expected = write_realsense_mcap(tmp_path / "rs.mcap")
    summary = ingest_path(log, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert summary["matched_frames"] == 3 and fs.intrinsics.width == 80
    got = fs.group["depth"][:].astype(np.int64)
    both = (got > 0) & (expected > 0)
    assert both.sum() > 0.97 * (expected > 0).sum()  # footprints cover the denser colour pixels
    err = np.median(np.abs(got - expected)[both])
    # the depth images as recorded, resampled as if aligned: what ingest did before registration existed
    from mcap.reader import make_reader

    from pipeline.ros2 import parse_image_cdr, raw_image_to_array

    with open(log, "rb") as f:
        raw = [raw_image_to_array(parse_image_cdr(m.data), where={})
               for _, _, m in make_reader(f).iter_messages(topics=["/camera/depth/image_rect_raw"])]
    naive = np.stack([cv2.resize(d, (80, 60), interpolation=cv2.INTER_NEAREST) for d in raw]).astype(np.int64)
    naive_err = np.median(np.abs(naive - expected)[(naive > 0) & (expected > 0)])
    # 96x72 depth: sampling alone gives ~1 cm on the slanted floor (it shrinks 4x at 4x the resolution)
    assert err <= 20 and err * 5 < naive_err, (err, naive_err)
    conv = " ".join(fs.attrs["provenance"]["conversions"])
    assert "registered into the colour camera" in conv and "camera_depth_optical_frame" in conv
    assert np.abs(fs.poses() - poses).max() < 1e-9


def test_missing_extrinsics_refused_naming_both_topics(tmp_path, capsys):
    log, _, _ = write_realsense_mcap(tmp_path / "rs.mcap", n=2, extrinsics=False)
    with pytest.raises(InputDataError, match=r"topic /camera/depth/image_rect_raw and /camera/color/image_raw: "
                                             r"depth \(frame 'camera_depth_optical_frame'\) is not aligned to colour"):
        ingest_path(log, tmp_path / "f.zarr", IngestParams(), **QUIET)
    assert not (tmp_path / "f.zarr").exists()
    code, err = cli_ingest(tmp_path, log, "rs", capsys=capsys)
    assert code == 1 and "/camera/depth/image_rect_raw and /camera/color/image_raw" in err and "no static tf" in err


def test_depth_on_another_frame_without_camera_info_is_refused(tmp_path):
    log, _, _ = write_realsense_mcap(tmp_path / "rs.mcap", n=2, depth_info=False)
    with pytest.raises(InputDataError, match=r"field ingest\.topics\.depth_camera_info: depth is on frame "
                                             r"'camera_depth_optical_frame', colour on 'camera_color_optical_frame'"):
        ingest_path(log, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_aligned_depth_topic_is_preferred(tmp_path):
    """A RealSense log with align_depth on holds both depth topics: the aligned one is used, unregistered."""
    from tests.fixtures.raw_datasets import RawLog, make_recording

    rec = make_recording(2)
    log = RawLog(tmp_path / "rs.mcap")
    for i, s in enumerate(rec.stamps.tolist()):
        log.image("/camera/color/image_raw", s, rec.rgb[i], "rgb8")
        log.camera_info("/camera/color/camera_info", s, rec.intrinsics)
        log.image("/camera/depth/image_rect_raw", s, np.zeros((30, 40), np.uint16), "16UC1",
                  frame="camera_depth_optical_frame")
        log.image("/camera/aligned_depth_to_color/image_raw", s, rec.depth_mm[i], "16UC1")
        log.camera_info("/camera/aligned_depth_to_color/camera_info", s, rec.intrinsics)
        log.pose("/camera/pose", s, rec.poses[i])
    log.close()
    ingest_path(tmp_path / "rs.mcap", tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert fs.attrs["provenance"]["topics"]["depth"] == "/camera/aligned_depth_to_color/image_raw"
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm)
    assert any("on the colour camera" in c for c in fs.attrs["provenance"]["conversions"])
