"""Replica (NICE-SLAM layout): depth scale, camera file, malformed sequences."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import cli_ingest, make_recording, write_replica

QUIET = {"log": lambda m: None}


def test_depth_scale_and_camera_file_above(tmp_path):
    rec = make_recording(3)
    root = write_replica(tmp_path, rec, cam_params_above=True)
    raw = __import__("cv2").imread(str(root / "results/depth000001.png"), -1)
    assert abs(int(raw[10, 10]) - rec.depth_mm[1, 10, 10] * 6.5535) <= 0.5  # stored at 6553.5 per metre
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert np.array_equal(fs.group["depth"][:], rec.depth_mm)
    assert fs.intrinsics.fx == pytest.approx(rec.intrinsics.fx)
    assert any("cam_params.json" in c for c in fs.attrs["provenance"]["conversions"])
    assert fs.attrs["world_up"]["source_up"] == "+z"


def test_short_trajectory_is_refused(tmp_path, capsys):
    root = write_replica(tmp_path, make_recording(3))
    lines = (root / "traj.txt").read_text().splitlines()
    (root / "traj.txt").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(InputDataError, match=r"traj\.txt: traj\.txt has 2 poses for 3 frames"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    code, err = cli_ingest(tmp_path, root, "r", "--format", "replica", capsys=capsys)
    assert code == 1 and "traj.txt has 2 poses for 3 frames" in err


def test_bad_pose_line_names_the_line(tmp_path):
    root = write_replica(tmp_path, make_recording(3))
    lines = (root / "traj.txt").read_text().splitlines()
    lines[1] = lines[1].replace(lines[1].split()[0], "nan")
    (root / "traj.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputDataError, match=r"traj\.txt; frame 1: pose contains NaN/inf"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_trajectory_that_is_not_text_and_truncated_jpeg(tmp_path):
    root = write_replica(tmp_path, make_recording(3))
    traj = root / "traj.txt"
    traj.write_bytes(b"\xb0" + traj.read_bytes()[1:])
    with pytest.raises(InputDataError, match="is not text") as e:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), log=lambda m: None)
    assert str(e.value).startswith(f"file {traj}; field line 1:")
