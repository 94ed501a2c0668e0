"""TSDF fusion: streaming, empty frames, honest failure on bad depth, and a canonical read-out order."""

import numpy as np
import pytest

from pipeline.config import ReconstructParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import Intrinsics
from pipeline.recon import tsdf
from pipeline.recon.store import canonical_point_order
from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames, write_frames

INTR = Intrinsics.from_hfov(96, 72, 90.0)


@pytest.fixture(scope="module")
def arrays():
    gt = box_room_gt()
    poses = box_room_poses(24)
    rgb, depth, _ = render_frames(gt, poses, INTR)
    return gt, poses, rgb, depth


def test_fusion_streams_blocks_and_surface_lies_on_the_walls(arrays, tmp_path):
    gt, poses, rgb, depth = arrays
    store = FrameStore(write_frames(tmp_path / "f.zarr", gt, rgb, depth, poses, INTR, block_frames=5))
    p = ReconstructParams(block_frames=7, min_weight=1.0)
    fusion = tsdf.fuse(store, p, frames=range(0, 24, 2))
    assert fusion.frames_fused == list(range(0, 24, 2)) and fusion.empty_frames == []
    xyz, normals, colors = tsdf.extract_points(fusion.volume, p)
    assert len(xyz) > 1000 and colors.dtype == np.uint8
    # Every surface point lies within a voxel of the floor plane, a wall face or an object face.
    faces_x = np.array([0.0, 4.0, 4.1, 6.0, 1.0, 2.0, 2.6, 3.0, 5.3, 5.9])
    faces_y = np.array([0.0, 3.0, 1.0, 2.0, 1.8, 2.6, 0.5, 0.9, 0.1, 0.6])
    faces_z = np.array([0.0, 0.75, 0.4, 1.2, 2.5])
    d = np.minimum.reduce([np.abs(xyz[:, 0:1] - faces_x).min(1), np.abs(xyz[:, 1:2] - faces_y).min(1),
                           np.abs(xyz[:, 2:3] - faces_z).min(1)])
    assert np.median(d) < 0.005 and np.percentile(d, 99) < p.voxel_size_m
    lattice, values = next(tsdf.iter_voxels(fusion.volume, p))
    assert lattice.dtype == np.int32 and values.min() >= -1 and values.max() <= 1


def test_a_few_empty_frames_are_skipped_and_reported(arrays, tmp_path):
    gt, poses, rgb, depth = arrays
    depth = depth.copy()
    depth[[3, 11]] = 0
    store = FrameStore(write_frames(tmp_path / "f.zarr", gt, rgb, depth, poses, INTR))
    fusion = tsdf.fuse(store, ReconstructParams())
    assert fusion.empty_frames == [3, 11] and len(fusion.frames_fused) == 22


def test_mostly_invalid_depth_fails_naming_the_first_frame(arrays, tmp_path):
    gt, poses, rgb, depth = arrays
    depth = depth.copy()
    depth[5:] = 0
    path = write_frames(tmp_path / "f.zarr", gt, rgb, depth, poses, INTR)
    with pytest.raises(InputDataError, match=r"field depth; frame 5: 19 of 24 frames have no valid depth"):
        tsdf.fuse(FrameStore(path), ReconstructParams())
    # Depth beyond depth_max_m counts as invalid too.
    with pytest.raises(InputDataError, match="frame 0: 24 of 24 frames"):
        tsdf.fuse(FrameStore(path), ReconstructParams(depth_min_m=0.1, depth_max_m=0.2))


def test_points_and_voxels_come_out_in_one_canonical_order_not_the_hash_maps(arrays, tmp_path):
    gt, poses, rgb, depth = arrays
    store = FrameStore(write_frames(tmp_path / "f.zarr", gt, rgb, depth, poses, INTR))
    p = ReconstructParams(min_weight=1.0)
    runs = []
    for _ in range(2):
        volume = tsdf.fuse(store, p).volume
        points = tsdf.extract_points(volume, p)
        chunks = list(tsdf.iter_voxels(volume, p, blocks_per_chunk=1))
        runs.append((points, chunks))
        # Points sorted by position, normal, colour; one block per chunk, blocks by block coordinate.
        assert (canonical_point_order(*points) == np.arange(len(points[0]))).all()
        blocks = np.array([lattice[0] // p.block_resolution for lattice, _ in chunks])
        assert all((lattice // p.block_resolution == b).all() for (lattice, _), b in zip(chunks, blocks))
        assert (np.lexsort(blocks.T[::-1]) == np.arange(len(blocks))).all() and len(np.unique(blocks, axis=0)) == len(blocks)
    (points_a, chunks_a), (points_b, chunks_b) = runs
    assert all(np.array_equal(a, b) for a, b in zip(points_a, points_b))
    assert len(chunks_a) == len(chunks_b)
    assert all(np.array_equal(la, lb) and np.array_equal(ta, tb) for (la, ta), (lb, tb) in zip(chunks_a, chunks_b))


@pytest.mark.parametrize(("intr", "expected"), [
    (Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480), 2),  # TUM fr1 Kinect: 0.025 * 516.5 / 5 = 2.58
    (Intrinsics(585.0, 585.0, 320.0, 240.0, 640, 480), 2),  # 7-Scenes Kinect: 2.93
    (Intrinsics.from_hfov(640, 480, 90.0), 1),  # f = 320: a stride-2 pixel at 5 m spans 31 mm > 25 mm
    (Intrinsics.from_hfov(320, 240, 90.0), 1),
    (Intrinsics(2000.0, 2000.0, 960.0, 540.0, 1920, 1080), 8),  # 10 by the rule, capped at 8
])
def test_auto_stride_keeps_a_pixel_at_the_farthest_depth_within_one_voxel(intr, expected):
    p = ReconstructParams()
    assert p.depth_stride == "auto"
    stride = tsdf.fusion_stride(p, intr)
    assert stride == expected
    assert stride == 1 or stride * p.depth_max_m / min(intr.fx, intr.fy) <= p.voxel_size_m
    assert tsdf.fusion_stride(ReconstructParams(depth_stride=3), intr) == 3
    assert tsdf.with_stride(p, intr).depth_stride == expected


def test_a_bad_depth_stride_is_refused():
    for bad in (0, 9, "half"):
        with pytest.raises(ValueError, match="depth_stride\n.*expected 'auto' or a whole number from 1 to 8"):
            ReconstructParams(depth_stride=bad)
