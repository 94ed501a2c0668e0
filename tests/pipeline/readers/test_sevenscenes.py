"""7-Scenes reader: synthesised stamps, invalid depth, malformed folders."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from stages.ingest import ingest_path
from tests.fixtures.raw_datasets import make_recording, write_7scenes

QUIET = {"log": lambda m: None}


def test_stamps_from_folder_fps_and_invalid_depth(tmp_path):
    rec = make_recording(4)
    root = write_7scenes(tmp_path, rec)
    ingest_path(root, tmp_path / "f.zarr", IngestParams(folder_fps=10.0), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert fs.stamps().tolist() == [0, 100_000_000, 200_000_000, 300_000_000]
    assert (fs.group["depth"][:][:, :2, :3] == 0).all()  # 65535 on disk -> 0
    assert fs.intrinsics.fx == pytest.approx(585.0 * 64 / 640)  # Kinect defaults rescaled to 64x48
    assert any("10.0 Hz" in c for c in fs.attrs["provenance"]["conversions"])


def test_missing_depth_file(tmp_path):
    root = write_7scenes(tmp_path, make_recording(3))
    (root / "frame-000001.depth.png").unlink()
    with pytest.raises(InputDataError, match=r"file .*frame-000001\.depth\.png; frame 1: frame-000001\.color\.png has "
                                             r"no depth\.png file"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_non_rigid_pose(tmp_path):
    rec = make_recording(3)
    rec.poses[2, :3, :3] *= 1.5
    root = write_7scenes(tmp_path, rec)
    with pytest.raises(InputDataError, match=r"topic frame-\*\.pose\.txt; frame 2: pose is not rigid"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
