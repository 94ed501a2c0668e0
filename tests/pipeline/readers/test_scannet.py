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


# ----------------------------------------------------------------------------- calibration files are input too

def _write_matrix(path, M) -> None:
    np.savetxt(path, np.asarray(M, dtype=float), fmt="%.6f")


@pytest.mark.parametrize("scale, words", [(np.diag([2.0, 2.0, 2.0, 1.0]), "the 3x3 part scales by 2 to 2"),
                                          (np.diag([1.0, 1.0, 1.5, 1.0]), "the 3x3 part scales by 1 to 1.5")])
def test_an_extrinsic_that_scales_is_refused_naming_the_file(tmp_path, capsys, scale, words):
    root = write_scannet(tmp_path, make_recording(2))
    _write_matrix(root / "intrinsic/extrinsic_depth.txt", scale)
    with pytest.raises(InputDataError) as err:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    text = str(err.value)
    assert f"file {root}/intrinsic/extrinsic_depth.txt" in text and words in text and "rigid transform" in text, text
    assert "depth/" not in text  # not blamed on the depth images
    assert not (tmp_path / "f.zarr").exists()
    code, out = cli_ingest(tmp_path, root, "s", capsys=capsys)
    assert code == 1 and "extrinsic_depth.txt" in out and "Traceback" not in out


@pytest.mark.parametrize("name, change, words", [
    ("intrinsic_depth.txt", {(0, 0): 0.0}, "depth intrinsics: focal lengths fx 0"),
    ("intrinsic_depth.txt", {(1, 1): -5.0}, "fy -5"),
    ("intrinsic_color.txt", {(0, 2): 1e6}, "colour intrinsics: principal point (1e+06"),
    ("intrinsic_color.txt", {(0, 1): 0.3}, "not a pinhole camera matrix"),
    ("intrinsic_depth.txt", {(0, 0): float("nan")}, "depth intrinsics hold NaN or inf"),
])
def test_intrinsics_that_cannot_project_are_refused_naming_the_file(tmp_path, name, change, words):
    root = write_scannet(tmp_path, make_recording(2))
    M = np.loadtxt(root / "intrinsic" / name)
    for at, value in change.items():
        M[at] = value
    _write_matrix(root / "intrinsic" / name, M)
    with pytest.raises(InputDataError) as err:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    assert f"file {root}/intrinsic/{name}" in str(err.value) and words in str(err.value), str(err.value)


def test_mixed_padded_and_plain_frame_names_name_both_files(tmp_path):
    root = write_scannet(tmp_path, make_recording(3))
    (root / "color/1.jpg").rename(root / "color/000001.jpg")
    with pytest.raises(InputDataError) as err:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    text = str(err.value)
    assert "mix zero-padded" in text and f"{root}/color/000001.jpg" in text and f"{root}/color/0.jpg" in text, text


def test_one_frame_number_twice_names_both_files(tmp_path):
    root = write_scannet(tmp_path, make_recording(3))
    (root / "color/2.jpg").rename(root / "color/02.jpg")
    (root / "color/2.jpg").write_bytes((root / "color/02.jpg").read_bytes())
    with pytest.raises(InputDataError, match=r"02\.jpg and 2\.jpg are both frame 2"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_an_export_padded_throughout_is_named(tmp_path):
    root = write_scannet(tmp_path, make_recording(2))
    for i in range(2):
        (root / f"color/{i}.jpg").rename(root / f"color/{i:06d}.jpg")
    with pytest.raises(InputDataError, match=r"frame names are zero-padded \(.*color/000000\.jpg\)"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
