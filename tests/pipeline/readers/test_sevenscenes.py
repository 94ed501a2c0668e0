"""7-Scenes reader: synthesised stamps, invalid depth, released (slightly skewed) poses in a y-down world,
malformed folders, and a rendered sequence through ingest -> reconstruct -> render."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zipon.cli import main
from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import rigid_error
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import make_recording, write_7scenes, write_7scenes_rendered

QUIET = {"log": lambda m: None}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The box room rendered as a released 7-Scenes sequence (24 frames, 320x240)."""
    return write_7scenes_rendered(tmp_path_factory.mktemp("sevenscenes"))


@pytest.fixture(scope="module")
def tilted(rendered, tmp_path_factory):
    """The rendered sequence as if its first Kinect frame had been pitched 12 deg: the y-down world is tilted."""
    import shutil

    root, poses, gt = rendered
    copy = tmp_path_factory.mktemp("tilted") / "seq-01"
    shutil.copytree(root, copy)
    a = np.radians(12.0)
    Rx = np.array([[1, 0, 0, 0], [0, np.cos(a), -np.sin(a), 0], [0, np.sin(a), np.cos(a), 0], [0, 0, 0, 1.0]])
    for f in sorted(copy.glob("frame-*.pose.txt")):
        np.savetxt(f, Rx @ np.loadtxt(f), fmt="%.7e")
    return copy, poses, gt


def test_stamps_from_folder_fps_and_invalid_depth(tmp_path):
    rec = make_recording(4)
    root = write_7scenes(tmp_path, rec)
    ingest_path(root, tmp_path / "f.zarr", IngestParams(folder_fps=10.0), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert fs.stamps().tolist() == [0, 100_000_000, 200_000_000, 300_000_000]
    assert (fs.group["depth"][:][:, :2, :3] == 0).all()  # 65535 on disk -> 0
    assert fs.intrinsics.fx == pytest.approx(585.0 * 64 / 640)  # Kinect defaults rescaled to 64x48
    assert any("10.0 Hz" in c for c in fs.attrs["provenance"]["conversions"])


def test_released_poses_are_reorthonormalised_and_turned_z_up(tmp_path):
    rec = make_recording(5)
    root = write_7scenes(tmp_path, rec, skew=2e-4, fmt="%.7e")
    on_disk = np.loadtxt(root / "frame-000003.pose.txt")
    assert 1e-4 < rigid_error(on_disk) < 1e-3  # as released: not rigid to the matcher's 1e-4
    logs = []
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), log=logs.append)
    assert ("world_up: the reader's documented convention: the dataset's world has -y up, not levelled: no level "
            "plane of 500+ depth samples in the first 5 frames; rotated onto +z") in logs  # random depth: no floor
    fs = FrameStore(tmp_path / "f.zarr")
    assert rigid_error(fs.poses()).max() < 1e-12
    assert np.abs(fs.poses() - rec.poses).max() < 1e-3  # y-down world -> the recording's z-up world
    assert fs.poses()[:, 2, 3] == pytest.approx(np.full(5, 0.88), abs=1e-6)  # camera height is world z
    up = fs.attrs["world_up"]
    assert up["setting"] == "dataset" and up["source_up"] == "-y"
    assert np.allclose(up["R_zup_from_source"], [[1, 0, 0], [0, 0, 1], [0, -1, 0]])


def test_stated_world_up_overrides_the_dataset(tmp_path):
    rec = make_recording(3)
    root = write_7scenes(tmp_path, rec)
    ingest_path(root, tmp_path / "f.zarr", IngestParams(world_up="+z"), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert fs.poses()[:, 1, 3] == pytest.approx(np.full(3, -0.88))  # left as the dataset's frame: height on -y
    assert fs.attrs["world_up"]["how"] == "stated by ingest.world_up: +z up"


def test_jpg_colour(tmp_path):
    rec = make_recording(3)
    root = write_7scenes(tmp_path, rec, ext="jpg")
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    assert fs.n_frames == 3
    on_disk = np.stack([cv2.imread(str(root / f"frame-{i:06d}.color.jpg"))[..., ::-1] for i in range(3)])
    assert np.array_equal(fs.group["rgb"][:], on_disk)  # decoded JPEG, BGR -> RGB


def test_skew_beyond_tolerance_is_refused_naming_the_file(tmp_path):
    root = write_7scenes(tmp_path, make_recording(3), skew=2e-4, fmt="%.7e")
    with pytest.raises(InputDataError, match=r"file .*frame-000000\.pose\.txt; frame 0: pose is not rigid "
                                             r"\(error .*\) \(expected a rotation orthonormal within "
                                             r"ingest\.pose_orthonormal_tol = 1e-05"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(pose_orthonormal_tol=1e-5), **QUIET)
    assert not (tmp_path / "f.zarr").exists()


def test_non_rigid_pose(tmp_path):
    rec = make_recording(3)
    rec.poses[2, :3, :3] *= 1.5
    root = write_7scenes(tmp_path, rec)
    with pytest.raises(InputDataError, match=r"file .*frame-000002\.pose\.txt; frame 2: pose is not rigid"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_missing_depth_file(tmp_path):
    root = write_7scenes(tmp_path, make_recording(3))
    (root / "frame-000001.depth.png").unlink()
    with pytest.raises(InputDataError, match=r"file .*frame-000001\.depth\.png; frame 1: frame-000001\.color\.png has "
                                             r"no depth\.png file"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)


def test_auto_world_up_finds_the_floor(rendered, tmp_path):
    root, poses, _ = rendered
    logs = []
    ingest_path(root, tmp_path / "f.zarr", IngestParams(world_up="auto"), log=logs.append)
    fs = FrameStore(tmp_path / "f.zarr")
    est = fs.attrs["world_up"]["estimate"]
    assert est["nearest_axis"] == "-y" and est["tilt_deg"] < 0.1
    assert any(m.startswith("world_up auto: floor-plane normal") for m in logs)
    # z-up as the simulator's world: optical axes and heights agree (heading is kept by the smallest rotation)
    assert np.abs(fs.poses()[:, 2, :] - poses[:, 2, :]).max() < 3e-3


def test_tilted_first_frame_is_levelled_on_the_floor(tilted, tmp_path):
    root, poses, _ = tilted
    logs = []
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), log=logs.append)
    fs = FrameStore(tmp_path / "f.zarr")
    up = fs.attrs["world_up"]
    assert up["source_up"] == "-y" and "levelled on the floor" in up["how"]
    assert up["estimate"]["tilt_deg"] == pytest.approx(12.0, abs=0.2)
    assert np.abs(fs.poses()[:, 2, :] - poses[:, 2, :]).max() < 5e-3  # optical axes and heights as rendered
    assert any("levelled on the floor" in m for m in logs)
    # stating the axis takes it literally: the floor stays 12 deg off
    ingest_path(root, tmp_path / "g.zarr", IngestParams(world_up="-y"), **QUIET)
    off = np.abs(FrameStore(tmp_path / "g.zarr").poses()[:, 2, :3] - poses[:, 2, :3]).max()
    assert off > np.sin(np.radians(12.0)) * 0.5


def test_auto_world_up_without_a_level_plane_is_refused(tmp_path):
    rec = make_recording(4)  # random depth: no plane anywhere
    root = write_7scenes(tmp_path, rec)
    with pytest.raises(InputDataError, match=r"field ingest\.world_up: world_up auto: no level plane .*set ingest\.world_up"):
        ingest_path(root, tmp_path / "f.zarr", IngestParams(world_up="auto"), **QUIET)
    assert not (tmp_path / "f.zarr").exists()


def test_released_sequence_ingest_reconstruct_render(tilted, tmp_path, capsys):
    """A 7-Scenes sequence as released (a y-down world tilted by its first frame, skewed poses) goes through
    ingest -> reconstruct -> render with no hand edits."""
    root, _, gt = tilted
    (tmp_path / "params.yaml").write_text(f"scenes:\n  kitchen: {{source: {root}}}\n"
                                          "reconstruct: {voxel_size_m: 0.05, depth_stride: 2}\n")
    base = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", str(tmp_path / "data"),
            "--manifests-dir", str(tmp_path / "manifests")]
    assert main(base + ["run", "-s", "kitchen", "--stage", "ingest", "--stage", "reconstruct"]) == 0
    assert main(base + ["render", "kitchen", "--what", "navigable", "-o", str(tmp_path / "nav.png")]) == 0
    assert (tmp_path / "nav.png").stat().st_size > 1000
    from pipeline.recon.store import Recon

    recon = Recon(tmp_path / "data" / "artifacts" / "kitchen" / "recon.zarr")
    assert abs(recon.floor_z - gt.floor_z) < 0.03
    assert recon.navigable.sum() * recon.grid.cell_size_m ** 2 > 3.0  # m^2 of the 18 m^2 box room


# ----------------------------------------------------------------------------- camera-intrinsics.txt (3DMatch layout)

# As the 3DMatch / TSDF-fusion data ship it: three rows of three numbers, tab or space separated
K_TEXT = " 5.7034e+01\t 0.0000e+00\t 3.2000e+01\t\n 0.0000e+00\t 5.7034e+01\t 2.4000e+01\t\n 0\t 0\t 1\t\n"


@pytest.mark.parametrize("where", ["scene folder above seq-01", "sequence folder"])
def test_camera_intrinsics_file_is_read_and_recorded(tmp_path, where):
    """fx = 570.34 at 640x480 (3DMatch), here 57.034 at 64x48: stored as the file says, not 7-Scenes' 585."""
    root = write_7scenes(tmp_path, make_recording(4))
    (tmp_path if where.startswith("scene") else root).joinpath("camera-intrinsics.txt").write_text(K_TEXT)
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    fs = FrameStore(tmp_path / "f.zarr")
    k = fs.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (57.034, 57.034, 32.0, 24.0, 64, 48)
    rel = "camera-intrinsics.txt" if where == "sequence folder" else "../camera-intrinsics.txt"
    assert fs.attrs["provenance"]["camera_intrinsics_file"] == {
        "path": rel, "K": [[57.034, 0.0, 32.0], [0.0, 57.034, 24.0], [0.0, 0.0, 1.0]]}
    assert any(c.startswith(f"intrinsics: {rel}") for c in fs.attrs["provenance"]["conversions"])


def test_camera_override_wins_over_the_file(tmp_path):
    root = write_7scenes(tmp_path, make_recording(3))
    (tmp_path / "camera-intrinsics.txt").write_text("not a matrix\n")
    params = IngestParams(camera_override={"fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0})
    ingest_path(root, tmp_path / "f.zarr", params, **QUIET)
    assert FrameStore(tmp_path / "f.zarr").intrinsics.fx == pytest.approx(50.0 * 64 / 640)


@pytest.mark.parametrize("text, says", [
    ("", r"shape \(0, 1\)"),
    ("570 0 320\n0 570 240\n", r"shape \(2, 3\)"),
    ("57 0 32\n0 57 24\n0 0 1\n0 0 1\n", r"shape \(4, 3\)"),
    ("57 0 32\n0 57\n0 0 1\n", "not numeric"),
    ("57 0 32\n0 57 24\n0 0 0\n", "not a pinhole"),
    ("-57 0 32\n0 57 24\n0 0 1\n", "do not fit"),
    ("inf 0 32\n0 57 24\n0 0 1\n", "NaN or inf"),
    ("57 0 32\n0 57 24\n0 0 1\n" + "#" * 5000, "file is 5022 bytes"),
])
def test_malformed_camera_intrinsics_file(tmp_path, text, says):
    root = write_7scenes(tmp_path, make_recording(2))
    (root / "camera-intrinsics.txt").write_text(text)
    with pytest.raises(InputDataError, match=says) as e:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    assert str(root / "camera-intrinsics.txt") in str(e.value)


def test_truncated_colour_and_depth_of_other_size_name_their_files(tmp_path):
    root = write_7scenes(tmp_path, make_recording(4))
    colour = root / "frame-000002.color.png"
    colour.write_bytes(colour.read_bytes()[:-20])
    with pytest.raises(InputDataError, match="truncated") as e:
        ingest_path(root, tmp_path / "f.zarr", IngestParams(), **QUIET)
    assert str(e.value).startswith(f"file {colour}; frame 2:")
    root = write_7scenes(tmp_path / "b", make_recording(4))
    depth = root / "frame-000001.depth.png"
    cv2.imwrite(str(depth), cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)[:, :32])
    with pytest.raises(InputDataError) as e:
        ingest_path(root, tmp_path / "g.zarr", IngestParams(), **QUIET)
    assert f"depth image {depth} is 32x48 but its colour image {root / 'frame-000001.color.png'} is 64x48" in str(e.value)
