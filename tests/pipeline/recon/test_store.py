"""recon.zarr's mesh and point files: canonical order, so the same surface gives the same bytes in any order."""

import numpy as np
import open3d as o3d

from pipeline.recon.store import canonical_mesh, canonical_point_order, read_mesh_geometry, write_mesh, write_points


def _mesh(vertices, triangles, colors):
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
                                     o3d.utility.Vector3iVector(np.asarray(triangles, np.int32)))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.asarray(colors, np.float64))
    return mesh


def test_a_mesh_in_any_vertex_order_with_duplicated_vertices_writes_the_same_bytes(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.uniform(0, 1, (40, 3))
    v[7, 0] = v[3, 0]  # ties in x broken by y
    c = rng.uniform(0, 1, (40, 3))
    tri = np.array([rng.choice(40, 3, replace=False) for _ in range(60)])
    # The same surface as open3d may hand it out: vertices permuted, and vertex 5 also stored twice
    # more (a zero crossing exactly at a voxel, once per edge) with triangles using the copies.
    perm = rng.permutation(40)
    inv = np.argsort(perm)
    v2, c2 = np.r_[v[perm], v[[5, 5]]], np.r_[c[perm], c[[5, 5]]]
    tri2 = inv[tri]
    uses5 = np.flatnonzero((tri == 5).any(axis=1))[:2]
    tri2[uses5[0]][tri[uses5[0]] == 5] = 40
    tri2[uses5[1]][tri[uses5[1]] == 5] = 41
    tri2 = np.roll(tri2[rng.permutation(len(tri2))], 1, axis=1)  # triangle order and starting corner too
    a, b = canonical_mesh(_mesh(v, tri, c)), canonical_mesh(_mesh(v2, tri2, c2))
    assert len(b.vertices) == 40
    for attr in ("vertices", "vertex_colors", "triangles", "vertex_normals"):
        assert np.array_equal(np.asarray(getattr(a, attr)), np.asarray(getattr(b, attr))), attr
    assert (np.diff(np.asarray(a.vertices)[:, 0]) >= 0).all()
    write_mesh(tmp_path / "a.ply", _mesh(v, tri, c))
    write_mesh(tmp_path / "b.ply", _mesh(v2, tri2, c2))
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    # A vertex at the same place with another colour is another vertex.
    c3 = c2.copy()
    c3[41] = [0.0, 0.0, 0.0]
    assert len(canonical_mesh(_mesh(v2, tri2, c3)).vertices) == 41


def test_points_in_any_order_write_the_same_bytes(tmp_path):
    rng = np.random.default_rng(1)
    xyz = np.round(rng.uniform(0, 1, (500, 3)), 2).astype(np.float32)  # many ties in x and y
    xyz[10] = xyz[11]  # two points at one place, told apart by their normals
    normals = rng.normal(size=(500, 3)).astype(np.float32)
    colors = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    order = canonical_point_order(xyz, normals, colors)
    keys = np.c_[xyz, normals, colors.astype(np.float32)][order]
    assert all(tuple(keys[i]) <= tuple(keys[i + 1]) for i in range(len(keys) - 1))
    perm = rng.permutation(500)
    write_points(tmp_path / "a.ply", xyz, normals, colors)
    write_points(tmp_path / "b.ply", xyz[perm], normals[perm], colors[perm])
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_canonical_point_order_is_the_sort_by_every_column():
    rng = np.random.default_rng(2)
    xyz = rng.integers(0, 6, (3000, 3)).astype(np.float32)  # positions shared by many rows
    xyz[rng.integers(0, 3000, 20)] = np.nan
    normals = rng.integers(0, 2, (3000, 3)).astype(np.float32)
    colors = rng.integers(0, 3, (3000, 3)).astype(np.uint8)
    keys = np.c_[xyz, normals, colors.astype(np.float32)]
    got = keys[canonical_point_order(xyz, normals, colors)]
    assert np.array_equal(got, keys[np.lexsort(keys.T[::-1])], equal_nan=True)
    distinct = xyz[~np.isnan(xyz).any(axis=1)][:50] + np.arange(50, dtype=np.float32)[:, None] * 10
    assert np.array_equal(canonical_point_order(distinct), np.lexsort(distinct.T[::-1]))


def _retouched(src, dst, **attrs):
    """A copy of the store ``src`` at ``dst`` with root attrs replaced (None removes a key)."""
    import json
    import shutil

    shutil.copytree(src, dst)
    meta = json.loads((dst / "zarr.json").read_text())
    for key, value in attrs.items():
        if value is None:
            meta["attributes"].pop(key, None)
        else:
            meta["attributes"][key] = value
    (dst / "zarr.json").write_text(json.dumps(meta))
    return dst


def test_a_buildings_store_reads_per_floor_and_refuses_what_does_not_fit(house, tmp_path):
    import pytest

    from pipeline.errors import ArtifactError
    from pipeline.recon import Recon

    _, recon, _ = house
    assert [f.id for f in recon.floors] == [0, 1] and recon.floor(1).grid == recon.grid
    assert recon.floor(1).height.shape == recon.height.shape and recon.floor(1).stats["floor_z_m"] > 2.5
    with pytest.raises(ArtifactError, match="no floor 2; this scene has 2 floors \\(0..1\\)"):
        recon.floor(2)
    with pytest.raises(ArtifactError, match="format_version 3, this zipon reads 1 and 2"):
        Recon(_retouched(recon.path, tmp_path / "v3.zarr", format_version=3))
    with pytest.raises(ArtifactError, match="attrs.floors missing in a format_version 2 store"):
        Recon(_retouched(recon.path, tmp_path / "nofloors.zarr", floors=None))
    moved = Recon(_retouched(recon.path, tmp_path / "moved.zarr",
                             floors=[{**f.model_dump(mode="json"), "id": f.id * 7} for f in recon.floors]))
    with pytest.raises(ArtifactError, match="floors/7 missing \\(floor 1 listed in attrs.floors\\)"):
        moved.floor(1)


def test_mesh_geometry_is_read_as_open3d_reads_it_from_our_files_and_any_other(tmp_path):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=0.5, resolution=8)
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.full((len(mesh.vertices), 3), 0.3))
    write_mesh(tmp_path / "ours.ply", mesh)
    o3d.io.write_triangle_mesh(str(tmp_path / "ascii.ply"), mesh, write_ascii=True)
    for name in ("ours.ply", "ascii.ply"):
        expected = o3d.io.read_triangle_mesh(str(tmp_path / name))
        vertices, triangles = read_mesh_geometry(tmp_path / name)
        assert vertices.dtype == np.float32 and triangles.dtype == np.uint32
        np.testing.assert_array_equal(vertices, np.asarray(expected.vertices, dtype=np.float32))
        np.testing.assert_array_equal(triangles, np.asarray(expected.triangles, dtype=np.uint32))
