"""navchat reader: Habitat base poses -> z-up optical camera poses, the quaternion-order quirk."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import habitat_to_world, pose_from_tq
from pipeline.readers import open_reader
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import cli_ingest, make_recording, navchat_base, write_navchat

QUIET = {"log": lambda m: None}


def test_camera_pose_is_z_up_above_the_base(tmp_path):
    root = write_navchat(tmp_path, make_recording(5, h=480, w=640))
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert fs.intrinsics.to_dict() == {"fx": 320.0, "fy": 320.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}
    for i, T in enumerate(fs.poses()):
        p, yaw = navchat_base(i)
        assert T[2, 3] == pytest.approx(p[1] + 0.88)  # height: Habitat y + camera height
        assert T[:2, 3] == pytest.approx([p[0], -p[2]])  # Habitat (x, z) -> world (x, -z)
        # optical axis horizontal, along the body's -z: Habitat (-sin, 0, -cos) -> world (-sin, cos, 0)
        assert T[:3, 2] == pytest.approx([-np.sin(yaw), np.cos(yaw), 0.0], abs=1e-12)
        assert T[:3, 1] == pytest.approx([0, 0, -1], abs=1e-12)  # image down = world down


def test_quaternion_order_quirk_is_undone(tmp_path):
    root = write_navchat(tmp_path, make_recording(2))
    # a base rotation that is not yaw-only: navchat stores (w, x, y, z)[::-1] = (z, y, x, w)
    q = np.array([0.1, 0.3, -0.2, 0.9])
    q /= np.linalg.norm(q)
    (root / "pose/abcScene_1.txt").write_text(" ".join(repr(float(x)) for x in [1.0, 0.0, 2.0, q[2], q[1], q[0], q[3]]))
    reader = open_reader(root, IngestParams(navchat_camera_height_m=0.5))
    poses = [s.payload for s in reader.samples(reader.open()) if s.stream == "pose"]
    assert np.abs(poses[1] - habitat_to_world(pose_from_tq(np.array([1.0, 0.0, 2.0]), q), 0.5)).max() < 1e-12


def test_two_scenes_in_one_folder(tmp_path):
    root = write_navchat(tmp_path, make_recording(2))
    (root / "rgb/abcScene_0.png").rename(root / "rgb/other_0.png")
    with pytest.raises(InputDataError, match=r"rgb/ holds scenes \['abcScene', 'other'\]"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_missing_pose_file(tmp_path):
    root = write_navchat(tmp_path, make_recording(3))
    (root / "pose/abcScene_2.txt").unlink()
    with pytest.raises(InputDataError, match=r"file .*pose/abcScene_2\.txt; frame 2: rgb/abcScene_2\.png has no pose file"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_folder_without_rgb_is_a_clear_error(tmp_path, capsys):
    
    root = write_navchat(tmp_path, make_recording(2))
    for f in (root / "rgb").iterdir():
        f.unlink()
    (root / "rgb").rmdir()
    with pytest.raises(InputDataError, match=r"file .*recordings/rgb: no rgb/ folder \(expected a navchat recording"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), fmt="navchat", **QUIET)
    code, err = cli_ingest(tmp_path, root, "n", "--format", "navchat", capsys=capsys)
    assert code == 1 and "no rgb/ folder" in err and "Traceback" not in err


def test_depth_array_cut_short_names_file_and_frame(tmp_path):
    root = write_navchat(tmp_path, make_recording(3))
    depth = sorted((root / "depth").glob("*.npy"))[1]
    depth.write_bytes(depth.read_bytes()[:-10])
    with pytest.raises(InputDataError, match="depth array could not be read") as e:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), log=lambda m: None)
    assert str(e.value).startswith(f"file {depth}; frame 1:")
