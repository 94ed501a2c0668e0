"""The slab-wise mesh writer: open3d's PLY records to the byte, and a triangle whose vertex no tile owns refused."""

import numpy as np
import open3d as o3d
import pytest

from pipeline.errors import StageError
from pipeline.recon import tiled_mesh


def test_records_and_header_are_the_bytes_open3d_writes(tmp_path):
    rng = np.random.default_rng(0)
    levels = np.arange(256 * 3).reshape(-1, 3) % 256
    colors = np.r_[rng.random((500, 3)), (levels + 0.5) / 255.0, levels / 255.0]  # halves round away from zero
    xyz, normals = rng.normal(size=(len(colors), 3)), rng.normal(size=(len(colors), 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    pcd.colors = o3d.utility.Vector3dVector(colors)
    assert o3d.io.write_point_cloud(str(tmp_path / "o3d.ply"), pcd, write_ascii=False, compressed=False)
    ours = tiled_mesh.ply_header(len(xyz), None) + tiled_mesh.vertex_records(xyz, normals, colors).tobytes()
    assert (tmp_path / "o3d.ply").read_bytes() == ours


def test_a_triangle_vertex_no_tile_owns_is_refused():
    table = np.array([[0.0, 0, 0, 0.1, 0.1, 0.1], [0.025, 0, 0, 0.1, 0.1, 0.1]])
    assert tiled_mesh._ranks(table, 10, table[::-1], "mesh.ply").tolist() == [11, 10]
    stray = np.array([[0.0, 0, 0, 0.1, 0.1, 0.2]])
    with pytest.raises(StageError, match="mesh.ply: a triangle's vertex is owned by no tile"):
        tiled_mesh._ranks(table, 0, stray, "mesh.ply")


def test_rows_found_by_hash_are_those_the_exact_search_finds_and_a_shared_hash_falls_back(monkeypatch):
    rng = np.random.default_rng(0)
    table = np.unique(np.round(rng.uniform(0, 1, (5000, 6)), 2), axis=0)
    rows = table[rng.integers(0, len(table), 20000)]
    want = tiled_mesh._ranks_by_sort(table, 7, rows, "mesh.ply")
    assert np.array_equal(tiled_mesh._ranks(table, 7, rows, "mesh.ply"), want)
    monkeypatch.setattr(tiled_mesh, "_row_hash", lambda r: np.zeros(len(r), np.uint64))  # every row collides
    assert np.array_equal(tiled_mesh._ranks(table, 7, rows, "mesh.ply"), want)


def test_a_parts_triangle_rows_are_saved_as_np_save_writes_them_gathered_a_block_at_a_time(tmp_path, monkeypatch):
    rng = np.random.default_rng(1)
    rows, index = rng.random((500, 6)), rng.integers(0, 500, (1000, 3))
    monkeypatch.setattr(tiled_mesh, "_GATHER", 64)  # many blocks and a partial last one
    for k, idx in enumerate((index, index[:0])):
        tiled_mesh._save_gathered(tmp_path / f"ours{k}.npy", rows, idx)
        np.save(tmp_path / f"numpy{k}.npy", rows[idx])
        assert (tmp_path / f"ours{k}.npy").read_bytes() == (tmp_path / f"numpy{k}.npy").read_bytes()
