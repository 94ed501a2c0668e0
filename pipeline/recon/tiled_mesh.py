"""The tiled reconstruction's mesh written a slab at a time: the bytes :func:`pipeline.recon.store.write_mesh` writes
for the whole mesh, with memory bounded by a slab.

Each tile spills its part of the mesh (:func:`spill_part`): the vertices it owns (by position,
:meth:`pipeline.recon.tiles.TileLayout.owner`) sorted by x, and its triangles with the rows (position,
colour) of their vertices, some owned by a neighbour. :func:`write_tiled_mesh` then walks the scene in slabs along
x. ``canonical_mesh`` orders vertices by x first, so the vertices of a slab, gathered from every tile, sorted and
merged as it does, are the next run of the whole mesh's vertices; a triangle goes with the slab of its first
(smallest) vertex, which holds the triangles' global order; its other vertices lie within a voxel, in the slab or
the next. A vertex's normal sums the normals of the triangles round it in triangle order (open3d's
``compute_vertex_normals``); those triangles start in its slab or the one before, so open3d computes each slab's
normals on those two slabs' triangles, in the same order, to the same bits. Vertex and face records go to two
files joined under the PLY header at the end.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d

from pipeline.errors import StageError
from pipeline.recon.store import canonical_point_order

_SLAB_M = 1.0  # slab width along x (at least a voxel: a triangle spans at most one)
_VERTEX = np.dtype([("xyz", "<f8", (3,)), ("normal", "<f8", (3,)), ("rgb", "u1", (3,))])
_FACE = np.dtype([("n", "u1"), ("index", "<u4", (3,))])
_GATHER = 1 << 18  # triangles gathered at once when a tile's part is spilled


def ply_header(n_vertices: int, n_faces: int | None) -> bytes:
    """The header open3d writes for a binary mesh (``n_faces`` given) or point cloud with normals and colours."""
    lines = ["ply", "format binary_little_endian 1.0", "comment Created by Open3D", f"element vertex {n_vertices}",
             *(f"property double {a}" for a in ("x", "y", "z", "nx", "ny", "nz")),
             *(f"property uchar {a}" for a in ("red", "green", "blue"))]
    if n_faces is not None:
        lines += [f"element face {n_faces}", "property list uchar uint vertex_indices"]
    return ("\n".join(lines + ["end_header"]) + "\n").encode()


def vertex_records(xyz: np.ndarray, normals: np.ndarray, colors01: np.ndarray) -> np.ndarray:
    """PLY vertex records as open3d writes them: colours in 0..1 scaled by 255, rounded half away from zero."""
    out = np.empty(len(xyz), _VERTEX)
    out["xyz"], out["normal"] = xyz, normals
    scaled = np.minimum(255.0, np.maximum(0.0, np.asarray(colors01, np.float64) * 255.0))
    whole = np.floor(scaled)
    out["rgb"] = (whole + (scaled - whole >= 0.5)).astype(np.uint8)
    return out


@dataclass
class SpilledPart:
    """One tile's mesh part on disk (:func:`spill_part`) and the x range its owned vertices and triangles span."""

    owned: Path  # (n, 6) float64 rows (x, y, z, r, g, b), sorted by x
    rows: Path  # (m, 3, 6) float64: each triangle's vertex rows
    first_x: Path  # (m,) float64: each triangle's smallest vertex x, ascending (rows in that order)
    owned_x: Path  # (n,) float64: the owned vertices' x (ascending)
    x_range: tuple[float, float]


def spill_part(vertices: np.ndarray, colors: np.ndarray, triangles: np.ndarray, owned: np.ndarray, stem: Path
               ) -> SpilledPart | None:
    """Write one tile's part: ``vertices``/``colors`` ``(n, 3)`` float64, ``triangles`` ``(m, 3)`` local indices,
    ``owned`` ``(n,)`` bool. None when it has neither owned vertices nor triangles."""
    rows = np.concatenate([vertices, colors], axis=1)
    mine = rows[owned]
    if not len(mine) and not len(triangles):
        return None
    mine = mine[np.argsort(mine[:, 0], kind="stable")]  # by x: the writer sorts each slab's rows from every tile
    tri_x = vertices[triangles, 0] if len(triangles) else np.zeros((0, 3))
    first_x = tri_x.min(axis=1)
    order = np.argsort(first_x, kind="stable")
    part = SpilledPart(stem.with_suffix(".owned.npy"), stem.with_suffix(".rows.npy"), stem.with_suffix(".x.npy"),
                       stem.with_suffix(".owned_x.npy"),
                       (float(min(mine[:, 0].min(initial=np.inf), first_x.min(initial=np.inf))),
                        float(max(mine[:, 0].max(initial=-np.inf), tri_x.max(initial=-np.inf)))))
    del tri_x
    np.save(part.owned, mine)
    np.save(part.owned_x, np.ascontiguousarray(mine[:, 0]))
    _save_gathered(part.rows, rows, triangles[order])
    np.save(part.first_x, first_x[order])
    return part


def _save_gathered(path: Path, rows: np.ndarray, index: np.ndarray) -> None:
    """``np.save(path, rows[index])`` (``rows`` ``(n, 6)`` float64, ``index`` ``(m, 3)``) without holding
    ``rows[index]``, the largest array of a tile's extraction (144 bytes a triangle): gathered and written
    :data:`_GATHER` triangles at a time."""
    header = {"descr": np.lib.format.dtype_to_descr(np.dtype("<f8")), "fortran_order": False,
              "shape": (len(index), 3, rows.shape[1])}
    with open(path, "wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
        for s in range(0, len(index), _GATHER):
            f.write(np.ascontiguousarray(rows[index[s : s + _GATHER]], "<f8").tobytes())


def _slab(arrays: list[Path], keys: list[Path | np.ndarray], lo: float, hi: float) -> np.ndarray | None:
    """The rows of each ``arrays[i]`` (a spilled ``.npy``, sorted by ``keys[i]``, a spilled ``.npy`` or an array)
    whose key lies in ``[lo, hi)``, concatenated; None when there are none.

    Each file is mapped only while its rows are copied out: pages of a long-lived map stay resident (the whole
    spill, gigabytes on a large floor, would count in the process's memory)."""
    parts = []
    for path, key in zip(arrays, keys):
        k = np.load(key, mmap_mode="r") if isinstance(key, Path) else key
        start, stop = int(np.searchsorted(k, lo)), int(np.searchsorted(k, hi))
        del k
        if stop > start:
            rows = np.load(path, mmap_mode="r")
            parts.append(np.array(rows[start:stop]))
            del rows
    return np.concatenate(parts) if parts else None


def _row_hash(rows: np.ndarray) -> np.ndarray:
    """``(k,)`` uint64: a hash of the bits of each float64 row ``(k, 6)`` (each word mixed in, then scrambled)."""
    bits = np.ascontiguousarray(rows, np.float64).view(np.uint64)
    h = np.full(len(rows), 0x9E3779B97F4A7C15, np.uint64)
    for j in range(bits.shape[1]):
        h = (h ^ bits[:, j]) * np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(31)
    return h


def _ranks(table: np.ndarray, base: int, rows: np.ndarray, where: str) -> np.ndarray:
    """Global index of each of ``rows`` ``(k, 6)`` in ``table`` (unique canonical rows, the first at ``base``).

    Looked up by a hash of the row's bits, each match checked row for row; should two rows share a hash, the exact
    (and slower) lexicographic search answers instead."""
    if len(table) and len(rows):
        th = _row_hash(table)
        order = np.argsort(th, kind="stable")
        sorted_h = th[order]
        qh = _row_hash(rows)
        at = order[np.minimum(np.searchsorted(sorted_h, qh), len(table) - 1)]
        if np.array_equal(table[at], rows):
            return base + at
    return _ranks_by_sort(table, base, rows, where)


def _ranks_by_sort(table: np.ndarray, base: int, rows: np.ndarray, where: str) -> np.ndarray:
    """:func:`_ranks` by one lexicographic sort of the table and the rows together."""
    keys = np.concatenate([table, rows])
    flag = np.r_[np.zeros(len(table)), np.ones(len(rows))]
    order = np.lexsort((flag, *keys.T[::-1]))
    is_table = flag[order] == 0
    last = np.maximum.accumulate(np.where(is_table, np.arange(len(order)), -1))
    found = order[np.maximum(last, 0)][~is_table]
    at = np.empty(len(rows), np.int64)
    at[order[~is_table] - len(table)] = found
    if (last[~is_table] < 0).any() or not np.array_equal(table[at], rows):
        raise StageError(f"{where}: a triangle's vertex is owned by no tile (tiled mesh): fuse with "
                         "run.recon_tile_m: 0")
    return base + at


def write_tiled_mesh(path: Path, parts: list[SpilledPart], workdir: Path) -> dict:
    """Write ``parts`` as one canonical binary PLY at ``path`` (as :func:`pipeline.recon.store.write_mesh` writes the
    whole mesh) and return the same description."""
    owned = [p.owned for p in parts]
    owned_x = [p.owned_x for p in parts]
    tri_rows = [p.rows for p in parts]
    tri_x = [p.first_x for p in parts]
    x0 = min(p.x_range[0] for p in parts)
    x1 = max(p.x_range[1] for p in parts)
    cuts = x0 + _SLAB_M * np.arange(int(np.floor((x1 - x0) / _SLAB_M)) + 2)
    vertex_file, face_file = workdir / "mesh_vertices.bin", workdir / "mesh_faces.bin"
    n_vertices = n_faces = 0
    lo_xyz, hi_xyz = np.full(3, np.inf), np.full(3, -np.inf)

    def slab_vertices(k: int) -> np.ndarray:
        rows = _slab(owned, owned_x, cuts[k], cuts[k + 1]) if k + 1 < len(cuts) else None
        if rows is None:
            return np.zeros((0, 6))
        rows = rows[canonical_point_order(rows[:, :3], rows[:, 3:])]
        first = np.r_[True, np.any(rows[1:] != rows[:-1], axis=1)]
        return rows[first]

    # a window of three slabs: vertices of k-1, k, k+1 (with the index of their first), triangles of k-1 and k
    prev_v, prev_base, prev_t = np.zeros((0, 6)), 0, np.zeros((0, 3), np.int64)
    cur_v, cur_base = slab_vertices(0), 0
    with open(vertex_file, "wb") as vf, open(face_file, "wb") as ff:
        for k in range(len(cuts) - 1):
            next_base = cur_base + len(cur_v)
            next_v = slab_vertices(k + 1)
            rows = _slab(tri_rows, tri_x, cuts[k], cuts[k + 1])
            tri = np.zeros((0, 3), np.int64)
            if rows is not None:
                window = np.concatenate([cur_v, next_v])
                tri = _ranks(window, cur_base, rows.reshape(-1, 6), str(path)).reshape(-1, 3)
                shift = np.argmin(tri, axis=1)
                tri = np.take_along_axis(tri, (shift[:, None] + np.arange(3)) % 3, axis=1)
                tri = tri[np.lexsort((tri[:, 2], tri[:, 1], tri[:, 0]))]
            if len(cur_v):
                verts = np.concatenate([prev_v, cur_v, next_v])
                # contiguous float64 / int32: open3d copies those at once, anything else an element at a time
                local = o3d.geometry.TriangleMesh(
                    o3d.utility.Vector3dVector(np.ascontiguousarray(verts[:, :3])),
                    o3d.utility.Vector3iVector((np.concatenate([prev_t, tri]) - prev_base).astype(np.int32)))
                local.compute_vertex_normals()
                normals = np.asarray(local.vertex_normals)[len(prev_v): len(prev_v) + len(cur_v)]
                vf.write(vertex_records(cur_v[:, :3], normals, cur_v[:, 3:]).tobytes())
                lo_xyz, hi_xyz = np.minimum(lo_xyz, cur_v[:, :3].min(axis=0)), np.maximum(hi_xyz, cur_v[:, :3].max(axis=0))
            if len(tri):
                faces = np.empty(len(tri), _FACE)
                faces["n"], faces["index"] = 3, tri
                ff.write(faces.tobytes())
            n_vertices += len(cur_v)
            n_faces += len(tri)
            prev_v, prev_base, prev_t = cur_v, cur_base, tri
            cur_v, cur_base = next_v, next_base
    with open(path, "wb") as out:
        out.write(ply_header(n_vertices, n_faces))
        for part in (vertex_file, face_file):
            with open(part, "rb") as f:
                shutil.copyfileobj(f, out, 1 << 24)
            part.unlink()
    return {"file": Path(path).name, "vertices": n_vertices, "triangles": n_faces,
            "bounds_min": np.round(lo_xyz, 4).tolist(), "bounds_max": np.round(hi_xyz, 4).tolist()}
