"""ScanNet exported scenes: invalid poses dropped and counted, colour resampled to the depth, depth registered."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import Intrinsics
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import cli_ingest, make_recording, write_scannet

QUIET = {"log": lambda m: None}


def test_invalid_poses_are_dropped_and_counted(tmp_path):
    rec = make_recording(6)
    root = write_scannet(tmp_path, rec, invalid_poses=(1, 2))
    summary = ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert summary["matched_frames"] == fs.n_frames == 4
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm[[0, 3, 4, 5]])
    assert np.abs(fs.poses() - rec.poses[[0, 3, 4, 5]]).max() < 1e-12
    assert fs.attrs["provenance"]["frames_dropped_invalid_pose"] == {"count": 2, "ranges": [[1, 2]]}


def test_colour_resampled_and_depth_registered(tmp_path):
    rec = make_recording(2, h=48, w=64)
    rec.depth_mm[:] = 1500  # a wall 1.5 m away, square to the camera
    depth_K = Intrinsics(25.0, 25.0, 31.5, 23.5, 64, 48)  # the depth camera: wider than the colour (f 32)
    root = write_scannet(tmp_path, rec, color_scale=2, depth_K=depth_K)
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert (fs.intrinsics.width, fs.intrinsics.height) == (64, 48)
    assert fs.intrinsics.fx == pytest.approx(rec.intrinsics.fx)  # colour K (2x) scaled back to the depth size
    depth = fs.group["depth"][:]
    assert set(np.unique(depth)) == {1500}  # the wider depth view covers every colour pixel, z unchanged
    conv = " ".join(fs.attrs["provenance"]["conversions"])
    assert "128x96 resampled to the depth's 64x48" in conv and "registered into the colour camera" in conv


def test_all_poses_invalid_is_refused(tmp_path, capsys):
    root = write_scannet(tmp_path, make_recording(2), invalid_poses=(0, 1))
    with pytest.raises(InputDataError, match=r"pose: all 2 poses are invalid \(-inf\)"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    code, err = cli_ingest(tmp_path, root, "s", capsys=capsys)
    assert code == 1 and "all 2 poses are invalid" in err


def test_missing_pose_file(tmp_path):
    root = write_scannet(tmp_path, make_recording(3))
    (root / "pose/2.txt").unlink()
    with pytest.raises(InputDataError, match=r"file .*pose/2\.txt; frame 2: color/2\.jpg has no pose file"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
