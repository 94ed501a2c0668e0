"""Line of sight on the reconstructed mesh, read a window at a time: memory bounded by the windows, not the floor.

:class:`~pipeline.nav.region.MeshSight` casts rays against one open3d ``RaycastingScene``. Holding the whole
``recon_mesh.ply`` in one scene costs memory with the floor's area (a 100 m x 60 m office's mesh is 34 M triangles,
5 GB as a scene). A goal region's rays never leave a small window: they run from cells within ``success_m`` of an
object's footprint to the object's mass centre, all inside the footprint's bounding box grown by ``success_m``.
:class:`WindowedSight` therefore casts each query against the triangles whose bounding box meets the query's
window only (:func:`read_windows`). The answers are the whole mesh's: a ray's verdict depends only on its first
hit short of the target (later hits count as clear), and any triangle that ray meets lies over the segment from
the cell to the target, inside the window; each triangle keeps its vertices' float32 positions and winding, so
its hit distance is the same bits.

Reading a window: ``recon_mesh.ply`` is written canonically (:func:`pipeline.recon.store.canonical_mesh`):
vertices sorted by position (x first), each triangle starting at its smallest vertex index and the triangles
sorted, and a marching-cubes triangle spans at most one voxel. So the triangles meeting ``x0 <= x <= x1`` start at
vertices with ``x0 - STRIP_MARGIN_M <= x <= x1``: one contiguous run of vertex records and of face records, found
by bisection on the file and read in chunks (:data:`CHUNK_FACES`). What is read is checked against those rules;
a file that breaks them (another tool's PLY) is read in full, chunk by chunk, with the same result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ArtifactError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.nav.region import MeshSight

STRIP_MARGIN_M = 1.0  # a triangle starting this far left of a window cannot reach it (it spans <= a voxel in x)
CHUNK_FACES = 1 << 20  # face records read at a time (13 MB, plus the vertex records they use)
WINDOW_EPS_M = 1e-3  # windows grow by this much: a ray ending on a window's edge stays inside it

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
              "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
              "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}


@dataclass(frozen=True)
class PlyLayout:
    """Where a binary little-endian triangle PLY keeps its vertex and face records (``None`` from :meth:`of` when
    the file is another kind: ASCII, big-endian, faces with other properties)."""

    path: Path
    vertex: np.dtype  # one vertex record (has fields x, y, z)
    face: np.dtype  # one face record: n (uint8, always 3), index (3,) uint32
    n_vertices: int
    n_faces: int
    vertex_offset: int

    @property
    def face_offset(self) -> int:
        return self.vertex_offset + self.n_vertices * self.vertex.itemsize

    @classmethod
    def of(cls, path: Path) -> PlyLayout | None:
        if not Path(path).is_file():
            raise MissingInputError(f"{path}: no mesh file to cast line of sight on (reconstruct writes it)")
        with open(path, "rb") as f:
            head = f.read(1 << 16)
        end = head.find(b"end_header\n")
        if not head.startswith(b"ply\n") or end < 0:
            return None
        lines = [ln.split() for ln in head[:end].decode("ascii", "replace").splitlines()[1:]]
        if ["format", "binary_little_endian", "1.0"] not in lines:
            return None
        elements: list[tuple[str, int, list[list[str]]]] = []
        for words in lines:
            if words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
                elements.append((words[1], int(words[2]), []))
            elif words[:1] == ["property"] and elements:
                elements[-1][2].append(words[1:])
        if [e[0] for e in elements[:2]] != ["vertex", "face"]:
            return None
        (_, n_v, v_props), (_, n_f, f_props) = elements[:2]
        names = [p[-1] for p in v_props]
        if any(len(p) != 2 or p[0] not in _PLY_TYPES for p in v_props) or {"x", "y", "z"} - set(names) or \
                len(set(names)) != len(names):
            return None
        if len(f_props) != 1 or f_props[0][:2] != ["list", "uchar"] or f_props[0][2] not in ("uint", "uint32",
                                                                                          "int", "int32"):
            return None
        vertex = np.dtype([(p[1], _PLY_TYPES[p[0]]) for p in v_props])
        face = np.dtype([("n", "u1"), ("index", _PLY_TYPES[f_props[0][2]], (3,))])
        layout = cls(Path(path), vertex, face, n_v, n_f, end + len(b"end_header\n"))
        size = Path(path).stat().st_size
        if size < layout.face_offset + n_f * face.itemsize:
            raise ArtifactError(f"{path}: the file ends inside its records ({size} bytes; its header promises "
                                f"{n_v} vertices and {n_f} triangles, {layout.face_offset + n_f * face.itemsize} "
                                "bytes)")
        return layout

    def vertices(self, f, start: int, stop: int) -> np.ndarray:
        """``(stop - start, 3)`` float32 positions of vertices ``start..stop-1`` (as the whole-mesh reader casts)."""
        f.seek(self.vertex_offset + start * self.vertex.itemsize)
        rec = np.fromfile(f, self.vertex, stop - start)
        return np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float32)

    def faces(self, f, start: int, stop: int) -> np.ndarray:
        """``(stop - start, 3)`` int64 vertex indices of faces ``start..stop-1``; refuses a face that is no triangle."""
        f.seek(self.face_offset + start * self.face.itemsize)
        rec = np.fromfile(f, self.face, stop - start)
        if len(rec) != stop - start:
            raise ArtifactError(f"{self.path}: the file ends inside its face records (face {start + len(rec)})")
        if (rec["n"] != 3).any():
            raise ArtifactError(f"{self.path}: face {start + int(np.argmax(rec['n'] != 3))} is not a triangle")
        index = rec["index"].astype(np.int64)
        if len(index) and (index.min() < 0 or index.max() >= self.n_vertices):
            raise ArtifactError(f"{self.path}: a face in {start}..{stop - 1} names a vertex out of range")
        return index

    def vertex_x(self, f, i: int) -> float:
        f.seek(self.vertex_offset + i * self.vertex.itemsize)
        return float(np.fromfile(f, self.vertex, 1)["x"][0])

    def first_index(self, f, i: int) -> int:
        f.seek(self.face_offset + i * self.face.itemsize)
        return int(np.fromfile(f, self.face, 1)["index"][0, 0])


def _bisect(n: int, below) -> int:
    """The first ``i`` in ``0..n`` where ``below(i)`` is False (``below`` True on a prefix)."""
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if below(mid):
            lo = mid + 1
        else:
            hi = mid
    return lo


class _NotCanonical(Exception):
    """What was read breaks the canonical order the strip reading relies on."""


@dataclass
class MeshWindow:
    """The triangles of a mesh whose bounding box meets ``box`` = (x0, y0, x1, y1) world metres: ``vertices``
    ``(n, 3)`` float32 and ``triangles`` ``(m, 3)`` uint32 (the file's vertex order and winding kept)."""

    box: tuple[float, float, float, float]
    vertices: np.ndarray
    triangles: np.ndarray

    def covers(self, box) -> bool:
        x0, y0, x1, y1 = box
        return self.box[0] <= x0 and self.box[1] <= y0 and x1 <= self.box[2] and y1 <= self.box[3]


class _Collector:
    """Per box, the triangles (global vertex ids and positions) found so far."""

    def __init__(self, boxes: np.ndarray):
        self.boxes = boxes
        self.ids: list[list[np.ndarray]] = [[] for _ in boxes]
        self.xyz: list[list[np.ndarray]] = [[] for _ in boxes]

    def add(self, index: np.ndarray, tri_xyz: np.ndarray, which=None) -> None:
        a, b, c = tri_xyz[:, 0, :2], tri_xyz[:, 1, :2], tri_xyz[:, 2, :2]  # (three 2-column minima: no axis reduce)
        lo, hi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
        for b in range(len(self.boxes)) if which is None else which:
            x0, y0, x1, y1 = self.boxes[b]
            keep = (hi[:, 0] >= x0) & (lo[:, 0] <= x1) & (hi[:, 1] >= y0) & (lo[:, 1] <= y1)
            if keep.any():
                self.ids[b].append(index[keep])
                self.xyz[b].append(tri_xyz[keep])

    def windows(self) -> list[MeshWindow]:
        out = []
        for b, box in enumerate(self.boxes):
            if not self.ids[b]:
                out.append(MeshWindow(tuple(map(float, box)), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)))
                continue
            ids, xyz = np.concatenate(self.ids[b]), np.concatenate(self.xyz[b])
            uniq, first, local = np.unique(ids.reshape(-1), return_index=True, return_inverse=True)
            out.append(MeshWindow(tuple(map(float, box)), xyz.reshape(-1, 3)[first],
                                  local.reshape(-1, 3).astype(np.uint32)))
        return out


def read_windows(mesh_path: Path, boxes) -> list[MeshWindow]:
    """The triangles of ``mesh_path`` meeting each of ``boxes`` ``(K, 4)`` (x0, y0, x1, y1 world metres), in one
    read of the file's strips (see the module docstring); a PLY that is not a canonical binary mesh is read in full
    (chunk by chunk when it is binary)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    layout = PlyLayout.of(Path(mesh_path))
    if layout is None:
        return _windows_of_whole(mesh_path, boxes)
    try:
        return _read_strips(layout, boxes)
    except _NotCanonical:
        return _read_all(layout, boxes)


def _windows_of_whole(mesh_path: Path, boxes: np.ndarray) -> list[MeshWindow]:
    from pipeline.recon.store import read_mesh_geometry

    v, t = read_mesh_geometry(mesh_path)
    out = _Collector(boxes)
    if len(t):
        index = t.astype(np.int64)
        out.add(index, v[index])
    return out.windows()


def _read_all(layout: PlyLayout, boxes: np.ndarray) -> list[MeshWindow]:
    out = _Collector(boxes)
    with open(layout.path, "rb") as f:
        for s in range(0, layout.n_faces, CHUNK_FACES):
            index = layout.faces(f, s, min(s + CHUNK_FACES, layout.n_faces))
            used = np.unique(index)  # in any order: gathered from runs of at most CHUNK_FACES vertex records
            xyz = np.empty((len(used), 3), np.float32)
            i = 0
            while i < len(used):
                j = int(np.searchsorted(used, used[i] + CHUNK_FACES))
                xyz[i:j] = layout.vertices(f, int(used[i]), int(used[j - 1]) + 1)[used[i:j] - used[i]]
                i = j
            out.add(index, xyz[np.searchsorted(used, index)])
    return out.windows()


def _strips(boxes: np.ndarray) -> list[tuple[float, float, list[int]]]:
    """Merged x ranges ``(x0 - margin, x1)`` of the boxes, each with the boxes it serves."""
    order = np.argsort(boxes[:, 0], kind="stable")
    strips: list[tuple[float, float, list[int]]] = []
    for b in order:
        lo, hi = boxes[b, 0] - STRIP_MARGIN_M, boxes[b, 2]
        if strips and lo <= strips[-1][1]:
            strips[-1] = (strips[-1][0], max(strips[-1][1], hi), strips[-1][2] + [int(b)])
        else:
            strips.append((lo, hi, [int(b)]))
    return strips


def _read_strips(layout: PlyLayout, boxes: np.ndarray) -> list[MeshWindow]:
    out = _Collector(boxes)
    with open(layout.path, "rb") as f:
        for lo, hi, which in _strips(boxes):
            v_lo = _bisect(layout.n_vertices, lambda i: layout.vertex_x(f, i) < lo)
            v_hi = _bisect(layout.n_vertices, lambda i: layout.vertex_x(f, i) <= hi)
            f_lo = _bisect(layout.n_faces, lambda i: layout.first_index(f, i) < v_lo)
            f_hi = _bisect(layout.n_faces, lambda i: layout.first_index(f, i) < v_hi)
            last_first = -1
            for s in range(f_lo, f_hi, CHUNK_FACES):
                index = layout.faces(f, s, min(s + CHUNK_FACES, f_hi))
                first = index[:, 0]
                if (index[:, 1] < first).any() or (index[:, 2] < first).any() or first[0] < last_first or \
                        (np.diff(first) < 0).any():
                    raise _NotCanonical
                last_first = int(first[-1])
                a, b = int(first[0]), int(index.max()) + 1
                xyz = layout.vertices(f, a, b)
                if (np.diff(xyz[:, 0]) < 0).any():
                    raise _NotCanonical
                tri = xyz[index - a]
                x = tri[:, :, 0]  # the first vertex is the leftmost (vertices sorted by x): no triangle reaches past
                if (np.maximum(x[:, 1], x[:, 2]) - x[:, 0] > STRIP_MARGIN_M).any():  # the margin
                    raise _NotCanonical
                out.add(index, tri, which)
    return out.windows()


class WindowedSight:
    """:class:`~pipeline.nav.region.MeshSight`'s line of sight on ``mesh_path``, each query cast against the mesh's
    triangles in a window around it (see the module docstring): the same answers, memory bounded by the windows.

    :meth:`prepare` reads the windows a caller will ask in, all in one read of the file; a query no read window
    covers reads its own. A window's ray-casting scene is built when first asked and kept until another window's
    is needed."""

    def __init__(self, mesh_path: Path, *, floor_z: float, camera_height_m: float, grid: GridSpec,
                 tolerance_m: float = 0.15):
        self.mesh_path, self.grid = Path(mesh_path), grid
        self.floor_z, self.cam_z, self.tolerance = float(floor_z), float(floor_z) + float(camera_height_m), \
            float(tolerance_m)
        self.windows: list[MeshWindow] = []
        self.reads = 0  # reads of the file (one per prepare or uncovered query)
        self._scene: tuple[int, MeshSight] | None = None

    def prepare(self, boxes) -> None:
        """Read the windows ``boxes`` ``(K, 4)`` (x0, y0, x1, y1 world metres) that no window read covers yet."""
        boxes = [tuple(map(float, b)) for b in np.asarray(boxes, np.float64).reshape(-1, 4)]
        todo = [b for b in boxes if not any(w.covers(b) for w in self.windows)]
        if todo:
            grown = np.asarray(todo) + np.array([-WINDOW_EPS_M, -WINDOW_EPS_M, WINDOW_EPS_M, WINDOW_EPS_M])
            self.windows += read_windows(self.mesh_path, grown)
            self.reads += 1

    def __call__(self, origins_xy: np.ndarray, target_xy, z_levels, own: np.ndarray, *, every: bool = False
                 ) -> np.ndarray:
        """As :meth:`MeshSight.__call__ <pipeline.nav.region.MeshSight.__call__>`."""
        o = np.asarray(origins_xy, np.float64).reshape(-1, 2)
        if not len(o):
            return np.full(0, bool(every))
        pts = np.vstack([o, np.asarray(target_xy, np.float64).reshape(1, 2)])
        box = (*pts.min(axis=0), *pts.max(axis=0))
        k = next((i for i, w in enumerate(self.windows) if w.covers(box)), None)
        if k is None:
            self.prepare([box])
            k = len(self.windows) - 1
        return self._sight(k)(o, target_xy, z_levels, own, every=every)

    def _sight(self, k: int) -> MeshSight:
        if self._scene is None or self._scene[0] != k:
            import open3d as o3d

            w = self.windows[k]
            scene = o3d.t.geometry.RaycastingScene()
            if len(w.triangles):
                scene.add_triangles(o3d.core.Tensor(w.vertices), o3d.core.Tensor(w.triangles))
            self._scene = None  # the previous window's scene goes before the next is built
            self._scene = (k, MeshSight(scene, cam_z=self.cam_z, floor_z=self.floor_z, grid=self.grid,
                                        tolerance_m=self.tolerance))
        return self._scene[1]
