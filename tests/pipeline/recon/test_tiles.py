"""Fusion in tiles: the same bytes as one volume, memory bounded by a tile, and a frame that leaves its predicted
footprint refused by name."""

import numpy as np
import open3d as o3d
import pytest
import zarr

from pipeline.config import GridParams, ReconstructParams
from pipeline.errors import StageError
from pipeline.frames import FrameStore
from pipeline.geometry import invert_pose
from pipeline.recon import tiles, tsdf
from pipeline.recon.build import reconstruct
from tests.fixtures.recon_scenes import write_box_room_frames

GRID = GridParams(rows=120, cols=160)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    path, _ = write_box_room_frames(tmp_path_factory.mktemp("tiles") / "frames.zarr", n_frames=24)
    return path


def _build(frames, out, p, tile_m):
    out.mkdir()
    summary = reconstruct(frames, out / "recon.zarr", out / "mesh.ply", out / "points.ply", p, GRID, tile_m=tile_m)
    group = zarr.open_group(str(out / "recon.zarr"), mode="r")
    arrays = {k: group[k][...] for k in group.array_keys()}
    return summary, arrays, (out / "mesh.ply").read_bytes(), (out / "points.ply").read_bytes()


@pytest.mark.parametrize("keyframes", [False, True])
def test_small_tiles_give_the_bytes_of_one_volume_holding_a_fraction_of_it(frames, tmp_path, keyframes):
    p = ReconstructParams(keyframes=keyframes)
    whole, whole_arrays, whole_mesh, whole_points = _build(frames, tmp_path / "whole", p, 0.0)
    tiled, tiled_arrays, tiled_mesh, tiled_points = _build(frames, tmp_path / "tiled", p, 2.0)
    assert "tiles" not in whole and tiled["tiles"]["fused"] >= 4  # a 6 x 3 m room in 2 m tiles
    assert tiled_mesh == whole_mesh and tiled_points == whole_points
    assert tiled_arrays.keys() == whole_arrays.keys()
    for key, value in whole_arrays.items():
        np.testing.assert_array_equal(tiled_arrays[key], value, err_msg=key)
    for key in ("tsdf_blocks", "points", "mesh_vertices", "mesh_triangles", "frames_fused", "cells_occupied",
                "cells_free", "cells_navigable", "keyframes"):
        assert tiled[key] == whole[key], key
    # memory: no tile's volume (its margin included) held more than half of the scene's blocks
    assert tiled["tiles"]["peak_blocks"] < whole["tsdf_blocks"] / 2


def test_a_scene_within_one_tile_fuses_one_volume(frames, tmp_path):
    summary, *_ = _build(frames, tmp_path / "one", ReconstructParams(), 40.0)
    assert "tiles" not in summary


def test_pose_refinement_keeps_one_volume(frames, tmp_path):
    summary, *_ = _build(frames, tmp_path / "refined", ReconstructParams(refine_poses=True), 1.2)
    assert "tiles" not in summary and summary["refinement"]["enabled"]


def test_voxels_and_blocks_are_each_owned_by_one_tile(frames, tmp_path):
    store = FrameStore(frames)
    p = ReconstructParams()
    fusion = tsdf.fuse(store, p)
    whole = np.concatenate([lat for lat, _ in tsdf.iter_voxels(fusion.volume, p, min_weight=p.occupancy_min_weight)])
    tiled = tiles.fuse_tiled(store, p, 2.0, tmp_path)
    parts = np.concatenate([lat for lat, _ in tiled.voxels()])
    assert tiled.n_blocks == fusion.n_blocks
    assert len(parts) == len(whole)
    np.testing.assert_array_equal(parts[np.lexsort(parts.T)], whole[np.lexsort(whole.T)])


def _blocks(volume):
    """A volume's block keys and each block's tsdf, weight and colour bits, sorted by key."""
    hashmap = volume.hashmap()
    active = hashmap.active_buf_indices().to(o3d.core.int64).numpy()
    keys = hashmap.key_tensor().numpy()[active]
    order = np.lexsort(keys.T[::-1])
    values = [volume.attribute(name).numpy().reshape(hashmap.capacity(), -1)[active[order]].view(np.uint32)
              for name in ("tsdf", "weight", "color")]
    return keys[order], values


def test_a_tile_fused_from_each_frames_blocks_found_once_has_the_bits_of_finding_them_per_tile_and_never_grows(
        frames, tmp_path):
    store = FrameStore(frames)
    p = tsdf.with_stride(ReconstructParams(), store.intrinsics)
    intr = tsdf.strided(store.intrinsics, p.depth_stride)
    footprints = tiles.frustum_blocks(store.poses().astype(np.float64), intr, p)
    layout = tiles.tile_layout(footprints, p, 2.0)
    touched = tiles._frame_plan(store, p, intr, np.ones(store.n_frames, bool), footprints,
                                tiles.TiledFusion(layout, tmp_path))
    assert sorted(touched) == list(range(store.n_frames))
    shares = {tile: tiles.tile_share(touched, np.arange(store.n_frames), *layout.block_range(tile, margin=1))
              for tile in layout.tiles()}
    tile = max(shares, key=lambda t: sum(map(len, shares[t].values())))  # the tile with the most to fuse
    lo, hi = layout.block_range(tile, margin=1)
    share = shares[tile]
    assert 0 < len(share) and any(len(share[i]) < len(touched[i]) for i in share)  # frames reaching past the tile
    volume = tiles._fuse_tile(store, p, intr, share)
    assert volume.hashmap().capacity() == tiles.volume_capacity(share)  # sized once: never rehashed

    # each frame read again, its blocks found again and cut to the tile, into a volume that grows from 16 blocks
    reference = tsdf.new_volume(p, block_count=16)
    K, K_integrate = o3d.core.Tensor(intr.K), o3d.core.Tensor(tsdf.integration_K(intr))
    trunc_mult = p.sdf_trunc_m / p.voxel_size_m
    block = tsdf.prepare_block(store.read(0, store.n_frames), p)
    for i in range(store.n_frames):
        depth = o3d.t.geometry.Image(o3d.core.Tensor(block.depth_mm[i]))
        extrinsic = o3d.core.Tensor(invert_pose(block.T_world_camera[i]))
        coords = reference.compute_unique_block_coordinates(depth, K, extrinsic, 1000.0, p.depth_max_m, trunc_mult)
        xy = coords.numpy()[:, :2]
        inside = np.flatnonzero(((xy >= lo) & (xy <= hi)).all(axis=1))
        if inside.size:
            reference.integrate(coords[o3d.core.Tensor(inside)], depth, o3d.t.geometry.Image(
                o3d.core.Tensor(block.rgb[i])), K_integrate, extrinsic, 1000.0, p.depth_max_m, trunc_mult)
    assert reference.hashmap().capacity() > 16
    keys, values = _blocks(volume)
    ref_keys, ref_values = _blocks(reference)
    np.testing.assert_array_equal(keys, ref_keys)
    for got, want, name in zip(values, ref_values, ("tsdf", "weight", "color")):
        np.testing.assert_array_equal(got, want, err_msg=name)


def test_a_volume_holds_the_blocks_before_a_frame_plus_the_frames_keys():
    # open3d grows when (blocks held + keys of one integrate) passes the capacity, even if the keys are held
    share = {3: np.array([[0, 0, 0], [1, 0, 0]], np.int32),
             7: np.array([[1, 0, 0], [2, 0, 0], [3, 0, 0]], np.int32),  # 2 held + 3 keys
             9: np.array([[0, 0, 0]], np.int32)}  # 4 held + 1 key
    assert tiles.volume_capacity(share) == 5
    assert tiles.volume_capacity({}) == 1
    # a tile's share keeps the blocks within its range, and no frame that has none there (or none at all)
    touched = {**share, 11: np.zeros((0, 3), np.int32)}
    kept = tiles.tile_share(touched, np.array([3, 7, 9, 11]), np.array([1, 0]), np.array([2, 0]))
    assert sorted(kept) == [3, 7] and kept[3].tolist() == [[1, 0, 0]] and kept[7].tolist() == [[1, 0, 0], [2, 0, 0]]


def test_ownership_boundaries_lie_half_a_voxel_before_a_tiles_first_voxel():
    layout = tiles.TileLayout(voxel_size_m=0.025, block_resolution=16, tile_blocks=2, first_block=(-1, 0),
                              shape=(3, 2))
    # tile 1 along x starts at block 1, voxel 16: x = 0.4 m; its core runs from 0.3875 m
    xy = np.array([[0.3874, 0.0], [0.3876, 0.0], [0.4, 0.0], [-5.0, 0.0], [9.0, 100.0]])
    np.testing.assert_array_equal(layout.owner(xy), [[0, 0], [1, 0], [1, 0], [0, 0], [2, 1]])
    lo, hi = layout.block_range((1, 0), margin=1)
    np.testing.assert_array_equal(lo, [0, -1])
    np.testing.assert_array_equal(hi, [3, 2])


def test_a_frame_reaching_past_its_predicted_footprint_is_refused_by_name(frames, tmp_path):
    store = FrameStore(frames)
    p = tsdf.with_stride(ReconstructParams(), store.intrinsics)
    intr = tsdf.strided(store.intrinsics, p.depth_stride)
    footprints = tiles.frustum_blocks(store.poses().astype(np.float64), intr, p)
    layout = tiles.tile_layout(footprints, p, 2.0)
    footprints[4] = footprints[4].mean(axis=0).astype(np.int64)  # a footprint of one block
    fusion = tiles.TiledFusion(layout, tmp_path)
    with pytest.raises(StageError, match=r"frame 4 touches TSDF blocks outside the footprint its pose predicts"):
        tiles._frame_plan(store, p, intr, np.ones(store.n_frames, bool), footprints, fusion)


def test_a_two_storey_house_in_tiles_gives_the_floors_stairs_and_bytes_of_one_volume(house, tmp_path):
    """Everything after fusion streams over the tiles' spilled points (floors, grid placement, each floor's band,
    stairs, points file): a building built in 4 m tiles is byte for byte the one-volume build."""
    whole, recon, _ = house
    frames = recon.path.parent / "frames.zarr"
    out = tmp_path / "tiled"
    out.mkdir()
    tiled = reconstruct(frames, out / "recon.zarr", out / "mesh.ply", out / "points.ply", ReconstructParams(),
                        GridParams(rows=160, cols=200), tile_m=4.0)
    assert tiled["tiles"]["fused"] >= 4 and len(whole["floors"]) == 2 and whole["stairs"]
    for key in ("floors", "floor_evidence", "stairs", "floor_stats", "grid_origin_xy", "grid_shape", "points",
                "cells_free", "cells_occupied", "cells_cleared_in_front_of_faces", "cells_occupied_by_tops"):
        assert tiled[key] == whole[key], key
    assert (out / "points.ply").read_bytes() == recon.points_path.read_bytes()
    assert (out / "mesh.ply").read_bytes() == recon.mesh_path.read_bytes()
    a, b = zarr.open_group(str(recon.path), mode="r"), zarr.open_group(str(out / "recon.zarr"), mode="r")
    for group in ("", "floors/1"):
        for key in a[group or "/"].array_keys() if group else a.array_keys():
            np.testing.assert_array_equal(b[f"{group}/{key}" if group else key][...],
                                          a[f"{group}/{key}" if group else key][...], err_msg=f"{group}/{key}")
