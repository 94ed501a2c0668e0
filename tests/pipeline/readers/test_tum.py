"""TUM RGB-D reader: the real fr1/rpy excerpt, intrinsics choice, and malformed folders."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.ingest_params import CameraOverride
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import pose_from_tq
from pipeline.readers import open_reader
from pipeline.readers.ingest import ingest_path
from pipeline.readers.tum import tum_depth_to_mm
from tests.fixtures.raw_datasets import make_recording, write_tum
from tests.fixtures.real_data import TUM_RPY as REAL

QUIET = {"log": lambda m: None}


def _rows(path: Path) -> list[list[str]]:
    return [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


def test_real_fr1_excerpt(tmp_path):
    s = ingest_path(REAL, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert s["matched_frames"] == fs.n_frames == 30
    assert fs.intrinsics.fx == 517.3 and fs.intrinsics.cy == 255.3
    rgb_rows, depth_rows, gt = _rows(REAL / "rgb.txt"), _rows(REAL / "depth.txt"), _rows(REAL / "groundtruth.txt")
    assert s["messages"] == {"depth": len(depth_rows), "rgb": len(rgb_rows), "world->camera": len(gt)}
    # frame 0: colour as stored, depth = round(raw / 5) mm, pose interpolated from the two bracketing gt lines
    first = fs.read(0, 1)
    assert np.array_equal(first.rgb[0], cv2.imread(str(REAL / rgb_rows[0][1]))[..., ::-1])
    raw = cv2.imread(str(REAL / depth_rows[0][1]), cv2.IMREAD_UNCHANGED)
    expect = np.round(raw / 5.0).astype(np.uint16)
    expect[(expect < 100) | (expect > 10000)] = 0
    assert np.array_equal(first.depth_mm[0], expect)
    t = float(rgb_rows[0][0])
    stamps = np.array([float(r[0]) for r in gt])
    j = np.searchsorted(stamps, t)
    a = (t - stamps[j - 1]) / (stamps[j] - stamps[j - 1])
    t_expect = (1 - a) * np.array(gt[j - 1][1:4], float) + a * np.array(gt[j][1:4], float)
    assert np.abs(first.T_world_camera[0, :3, 3] - t_expect).max() < 1e-6
    R_near = pose_from_tq(np.array(gt[j][1:4], float), np.array(gt[j][4:], float))[:3, :3]
    assert np.abs(first.T_world_camera[0, :3, :3] - R_near).max() < 0.02  # 10 ms of rpy motion
    assert fs.stamps()[0] == 1305031229528748000


def test_depth_scale():
    raw = np.array([[0, 1, 2, 3, 5, 5000, 65535]], dtype=np.uint16)
    assert tum_depth_to_mm(raw).tolist() == [[0, 0, 0, 1, 1, 1000, 13107]]


def test_intrinsics_from_folder_name_and_override(tmp_path):
    root = write_tum(tmp_path, make_recording(2, h=480, w=640), name="rgbd_dataset_freiburg2_xyz")
    assert open_reader(root, IngestParams()).open().info.intrinsics.fx == 520.9
    assert open_reader(root, IngestParams(tum_camera="fr3")).open().info.intrinsics.fx == 535.4
    o = CameraOverride(fx=500, fy=501, cx=320, cy=240)
    assert open_reader(root, IngestParams(camera_override=o)).open().info.intrinsics.fy == 501


def test_listed_file_missing(tmp_path):
    root = write_tum(tmp_path, make_recording(3))
    missing = _rows(root / "rgb.txt")[1][1]
    (root / missing).unlink()
    with pytest.raises(InputDataError, match=rf"file .*{missing}; field rgb\.txt line 4; frame 1: rgb\.txt line 4 lists "
                                             r"a missing file \(expected the image file to exist\)"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_non_unit_quaternion(tmp_path):
    root = write_tum(tmp_path, make_recording(3))
    lines = (root / "groundtruth.txt").read_text().splitlines()
    parts = lines[3].split()
    parts[4:8] = ["0.5", "0.5", "0.5", "0.0"]
    lines[3] = " ".join(parts)
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputDataError, match=r"groundtruth\.txt; field line 4; frame 2: pose quaternion has norm "
                                             r"0\.866025: not a rotation"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_real_excerpt_world_up_auto_finds_z_up(tmp_path):
    """The real fr1/rpy excerpt: the camera pitches ~45 deg down and rolls on purpose; auto still finds the
    level desk/floor and the mocap world's +z (a couple of degrees off: the mocap frame is not levelled)."""
    logs = []
    ingest_path(REAL, tmp_path / "f.zarr", IngestParams(world_up="auto"), log=logs.append)
    est = FrameStore(tmp_path / "f.zarr").attrs["world_up"]["estimate"]
    assert est["nearest_axis"] == "+z" and est["tilt_deg"] < 5.0 and est["plane_points"] > 10_000
    assert any(m.startswith("world_up auto:") for m in logs)


def test_text_that_is_not_utf8_or_not_numeric_names_file_and_line(tmp_path):
    """Both were Python exceptions (UnicodeDecodeError, ValueError) until the fuzzers found them."""
    root = write_tum(tmp_path, make_recording(4))
    gt = root / "groundtruth.txt"
    lines = gt.read_text().splitlines()
    parts = lines[2].split()
    lines[2] = " ".join(parts[:2] + ["-0.00;999"] + parts[3:])
    gt.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputDataError, match="pose is not numeric") as e:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    assert str(e.value).startswith(f"file {gt}; field line 3; frame 1:")
    rgb = root / "rgb.txt"
    rgb.write_bytes(rgb.read_bytes().replace(b"# timestamp", b"# \xb0timestamp"))
    with pytest.raises(InputDataError, match="byte 0xb0 at offset") as e:
        ingest_path(root, tmp_path / "g.zarr", IngestParams(), **QUIET)
    assert str(e.value).startswith(f"file {rgb}; field line 2:")
