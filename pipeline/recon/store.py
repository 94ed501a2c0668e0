"""``recon.zarr`` (+ ``recon_mesh.ply`` / ``recon_points.ply`` beside it): the reconstruction artifact.

Format (version 1: one floor; version 2: a building of several floors, see below)::

    recon.zarr/                  attrs: artifact="recon", format_version, stage, params_digest, code_version,
    │                                   grid {rows, cols, cell_size_m, origin_xy, orientation} (GridSpec.to_attrs),
    │                                   floor_z (world z of the floor, m), floor_estimated (bool),
    │                                   robot_radius_m, height_band_m [lo, hi] (obstacle band above the floor),
    │                                   occupancy_codes {"0": "unknown", "1": "free", "2": "occupied"},
    │                                   tsdf {voxel_size_m, sdf_trunc_m, min_weight, occupancy_min_weight,
    │                                         depth_range_m, depth_stride, blocks},
    │                                   mesh {file, vertices, triangles, bounds_min, bounds_max},
    │                                   points {file, count}, frames {n_frames, fused, empty},
    │                                   refinement {enabled, max_moved_m, median_moved_m, frames_rejected, ...},
    │                                   keyframes {enabled, translation_m, rotation_deg, novel_fraction, keyframes,
    │                                              frames_with_depth, kept_fraction, reasons} (pipeline.recon.keyframes),
    │                                   stats {cells_*, points_outside_*, floor_points},
    │                                   units, conventions
    ├── occupancy  (rows, cols)    uint8    0 unknown, 1 free, 2 occupied (navchat's codes)
    ├── navigable  (rows, cols)    bool     free and clear of occupied cells by robot_radius_m
    ├── color      (rows, cols, 3) uint8    RGB of the highest surface (ceilings excluded), 0 unknown
    ├── height     (rows, cols)    float32  metres above floor_z of the highest surface, NaN unknown
    ├── pose       (N, 4, 4)       float64  T_world_camera used for fusion (refined when refine_poses;
    │                                       frames.zarr is never modified); a frame that was not a keyframe has
    │                                       the pose it would have been fused with; NaN: no valid depth
    └── fused      (N,)            bool     frame i went into the volume (with keyframes on: i is a keyframe)

A building (more than one floor, :mod:`pipeline.recon.floors`) is written as version 2: the root keeps
floor 0's grids exactly as above (``grid``, ``floor_z``, ``stats`` and the four arrays are floor 0's, so a
reader of floor 0 needs nothing new), and adds::

    recon.zarr/                  attrs (added): floors [{id, name, floor_z_m, ceiling_z_m, source, frames}],
    │                                           stairs [{id, kind, bottom {floor, cells, endpoint, xy, z_m},
    │                                                    top {...}, rise_m, run_m, length_m, flight_cells,
    │                                                    flight_bbox}] (:class:`StairLink`)
    └── floors/                  only in a building
        └── <id>/                attrs: grid, floor_z, stats (as the root's, for floor <id> >= 1)
            └── occupancy, navigable, color, height    only in a building (as the root's, on that floor's grid)

A single-floor store is written as version 1, byte for byte as before floors existed: no ``floors`` attrs
(unless the floor was pinned with ``reconstruct.floors``, whose record it keeps), no ``floors/`` group;
:class:`Recon` reads it as one floor (id 0, ``floor_z``, ceiling unknown). Which floor
a world height belongs to is :func:`floor_bands` of the floor list, nowhere else.

Grids are chunked in 128x128-cell spatial tiles (the whole colour axis in a chunk). Meshes are
binary PLY with vertex colours and normals, in world metres; vertices and triangles are stored
in a canonical (sorted) order so the same inputs give the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import ValidationError

from pipeline.errors import ArtifactError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.store import ArtifactAttrs, AttrsModel, GridAttrs, compressor, new_group, open_group

if TYPE_CHECKING:  # open3d is imported where meshes and points are written or read: reading the grids needs none
    import open3d as o3d

ARTIFACT = "recon"
FORMAT_VERSION = 1  # one floor (every store before floors existed)
BUILDING_FORMAT_VERSION = 2  # several floors: a floors/ group and floors/stairs attrs
FLOOR_GROUP = "floors"  # floors/<id>/ holds floor <id>'s grids (id >= 1; floor 0's are the root's)
BAND_MARGIN_M = 0.15  # a floor's points start this far below it (its slab's top, seen from above)
TILE = 128
MESH_SUFFIX = "_mesh.ply"
POINTS_SUFFIX = "_points.ply"
UNITS = {"height": "m above floor_z", "floor_z": "m (world z)", "grid": "m", "color": "8-bit RGB"}
UNKNOWN, FREE, OCCUPIED = 0, 1, 2
OCCUPANCY_CODES = {UNKNOWN: "unknown", FREE: "free", OCCUPIED: "occupied"}


# ----------------------------------------------------------------------------- the store's types


@dataclass
class Grids:
    """The top-down products of one reconstruction (arrays ``(rows, cols[, 3])``), as :func:`write_recon` stores them."""

    grid: GridSpec
    floor_z: float
    occupancy: np.ndarray  # uint8 codes
    navigable: np.ndarray  # bool
    color: np.ndarray  # uint8 RGB of the highest surface
    height: np.ndarray  # float32 metres above the floor, NaN unknown
    stats: dict = field(default_factory=dict)


class Floor(AttrsModel):
    """One floor of the scene (``attrs.floors[i]``; :mod:`pipeline.recon.floors` finds them)."""

    id: int
    name: str
    floor_z_m: float  # world z of the walkable surface
    ceiling_z_m: float | None = None  # world z of the ceiling above it; None: not seen
    source: Literal["surface", "cameras", "pinned"] = "surface"  # how floor_z_m was found
    frames: int = 0  # frames whose camera stood on this floor


class Landing(AttrsModel):
    """Where a stair flight meets a floor: ``cells`` (row, col) of that floor's grid next to the flight, and
    ``endpoint``, the navigable cell (else the landing cell) nearest their centre, where routes join."""

    floor: int
    cells: list[tuple[int, int]]
    endpoint: tuple[int, int]
    xy: tuple[float, float]  # world x, y of the endpoint's centre, metres
    z_m: float


class StairLink(AttrsModel):
    """A connected climb of walkable surface (stairs or a ramp) between two floors (``attrs.stairs[i]``)."""

    id: int
    kind: Literal["stairs", "ramp"]
    bottom: Landing
    top: Landing
    rise_m: float  # top.z_m - bottom.z_m
    run_m: float  # horizontal length of the shortest walk over the flight, foot to head
    length_m: float  # its length in 3-D (at least hypot(rise, run)): what routes add for the climb
    flight_cells: int  # cells of the flight (treads) in the bottom floor's grid
    flight_bbox: tuple[int, int, int, int]  # row0, col0, row1, col1 (inclusive) of the flight in that grid


def floor_bands(floors: list[Floor] | tuple[Floor, ...]) -> list[tuple[float, float]]:
    """``[(lo, hi)]`` world z of each floor's band (floors sorted by height): floor k holds what lies in
    ``[floor_z_k - BAND_MARGIN_M, floor_z_k+1 - BAND_MARGIN_M)``; the lowest band starts at -inf, the highest
    ends at +inf (one floor: everything)."""
    cuts = [f.floor_z_m - BAND_MARGIN_M for f in floors[1:]]
    return list(zip([-np.inf, *cuts], [*cuts, np.inf]))


def floor_of_z(floors: list[Floor] | tuple[Floor, ...], z: np.ndarray) -> np.ndarray:
    """Index of the floor (:func:`floor_bands`) each world height ``z`` (any shape, metres) belongs to, int64."""
    cuts = np.array([f.floor_z_m - BAND_MARGIN_M for f in floors[1:]], dtype=np.float64)
    return np.searchsorted(cuts, np.asarray(z, dtype=np.float64), side="right").astype(np.int64)


class MeshAttrs(AttrsModel):
    """``attrs.mesh``: the PLY beside the store (:func:`write_mesh`)."""

    file: str
    vertices: int
    triangles: int
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]


class PointsAttrs(AttrsModel):
    """``attrs.points``: the surface points PLY beside the store (:func:`write_points`)."""

    file: str
    count: int


class ReconAttrs(ArtifactAttrs):
    """The attrs of ``recon.zarr`` (the tree above); the reconstruct stage's figures are optional."""

    grid: GridAttrs
    floor_z: float
    robot_radius_m: float
    height_band_m: tuple[float, float]
    occupancy_codes: dict[str, str]
    floor_estimated: bool | None = None
    tsdf: dict[str, Any] | None = None
    mesh: MeshAttrs | None = None
    points: PointsAttrs | None = None
    frames: dict[str, Any] | None = None
    refinement: dict[str, Any] | None = None
    keyframes: dict[str, Any] | None = None
    stats: dict[str, Any] = {}
    units: dict[str, str] = {}
    conventions: dict[str, str] | None = None
    floors: list[Floor] | None = None  # version 2 (a building) only
    stairs: list[StairLink] | None = None


class FloorGridAttrs(AttrsModel):
    """The attrs of ``floors/<id>/`` in a building's store."""

    grid: GridAttrs
    floor_z: float
    stats: dict[str, Any] = {}


# array -> (zarr dimension_names, units and meaning) so `xarray.open_zarr(recon.zarr)` names every axis
ARRAY_DIMS: dict[str, tuple[tuple[str, ...], dict]] = {
    "occupancy": (("row", "col"), {"units": "1", "long_name": "0 unknown, 1 free, 2 occupied"}),
    "navigable": (("row", "col"), {"units": "1", "long_name": "free and clear of obstacles by robot_radius_m"}),
    "color": (("row", "col", "rgb"), {"units": "8-bit RGB", "long_name": "colour of the highest surface"}),
    "height": (("row", "col"), {"units": "m", "long_name": "height of the highest surface above floor_z"}),
    "pose": (("frame", "pose_row", "pose_col"), {"units": "m", "long_name": "T_world_camera used for fusion"}),
    "fused": (("frame",), {"units": "1", "long_name": "frame went into the volume"}),
}


def write_recon(path: Path, grids: Grids | list[Grids], poses: np.ndarray, fused: np.ndarray, attrs: dict, *,
                floors: list[Floor] | None = None, stairs: list[StairLink] | None = None) -> None:
    """Write a new ``recon.zarr`` at ``path`` (``attrs`` from :func:`pipeline.store.artifact_attrs` + figures).

    ``grids``: one floor's, or one per floor of ``floors`` (in order); more than one floor writes version 2
    (the module doc), one floor writes version 1 exactly as before floors existed (with ``floors`` given, a
    ``floors`` attr is added: a floor pinned with ``reconstruct.floors``).
    """
    per_floor = [grids] if isinstance(grids, Grids) else list(grids)
    building = len(per_floor) > 1
    if (building or floors is not None) and (floors is None or len(floors) != len(per_floor)):
        raise ValueError(f"{path}: {len(per_floor)} floors' grids need as many floors records")
    first = per_floor[0]
    extra = {}
    if floors is not None:  # one floor: only when pinned by name (reconstruct.floors); else the store stays as it was
        extra["floors"] = [f.model_dump(mode="json") for f in floors]
    if building:
        extra.update(format_version=BUILDING_FORMAT_VERSION, stairs=[s.model_dump(mode="json") for s in stairs or []])
    group = new_group(Path(path), ReconAttrs.checked({
        **attrs,
        "grid": first.grid.to_attrs(),
        "floor_z": float(first.floor_z),
        "occupancy_codes": {str(k): v for k, v in OCCUPANCY_CODES.items()},
        "units": UNITS,
        "stats": first.stats,
        **extra,
    }, path))
    _write_grids(group, first)
    c = compressor(shuffle="noshuffle")
    for name, (data, chunks, codec, a) in {
        "pose": (poses.astype(np.float64), (max(len(poses), 1), 4, 4), compressor(), {"frame": "T_world_camera"}),
        "fused": (fused.astype(bool), (max(len(fused), 1),), c, {}),
    }.items():
        _write_array(group, name, data, chunks, codec, a)
    for floor, g in zip(floors[1:] if building else [], per_floor[1:]):
        sub = group.require_group(FLOOR_GROUP).create_group(str(floor.id))
        floor_attrs = {"grid": g.grid.to_attrs(), "floor_z": float(g.floor_z), "stats": g.stats}
        FloorGridAttrs.model_validate(floor_attrs)  # a writer never stores attrs its reader refuses
        sub.attrs.update(floor_attrs)
        _write_grids(sub, g)


def _write_grids(group, grids: Grids) -> None:
    """The four top-down arrays of one floor, in 128x128-cell tiles."""
    g = grids.grid
    tile = (min(TILE, g.rows), min(TILE, g.cols))
    c = compressor(shuffle="noshuffle")
    arrays = {
        "occupancy": (grids.occupancy.astype(np.uint8), tile, c, {"codes": {str(k): v for k, v in OCCUPANCY_CODES.items()}}),
        "navigable": (grids.navigable.astype(bool), tile, c, {}),
        "color": (grids.color.astype(np.uint8), tile + (3,), c, {"unit": "8-bit RGB"}),
        "height": (grids.height.astype(np.float32), tile, compressor(shuffle="shuffle"),
                   {"unit": "m above floor_z", "unknown": "NaN"}),
    }
    for name, (data, chunks, codec, a) in arrays.items():
        _write_array(group, name, data, chunks, codec, a)


def _write_array(group, name: str, data: np.ndarray, chunks: tuple, codec, a: dict) -> None:
    dims, meaning = ARRAY_DIMS[name]
    arr = group.create_array(name, shape=data.shape, chunks=chunks, dtype=data.dtype, compressors=codec,
                             fill_value=np.nan if data.dtype == np.float32 else 0, dimension_names=dims)
    arr[...] = data
    arr.attrs.update({**meaning, **a})


def canonical_point_order(*columns: np.ndarray) -> np.ndarray:
    """Indices sorting rows lexicographically by all ``columns`` (each ``(N, c)``), the first column first.

    Rows equal in every column are interchangeable, so the sorted arrays do not depend on the input order.
    The rows are sorted by the first array (positions: nearly all distinct) and only the runs it leaves tied are
    sorted by every column: the same order as one sort by all of them, at a third of its cost for a scene's
    million points.
    """
    first = np.asarray(columns[0]).reshape(len(columns[0]), -1)
    order = np.lexsort(first.T[::-1])
    ranked = first[order]
    tie = np.all((ranked[1:] == ranked[:-1]) | (np.isnan(ranked[1:]) & np.isnan(ranked[:-1])), axis=1)
    if len(columns) == 1 or not tie.any():
        return order
    run = np.cumsum(np.r_[True, ~tie])  # rows of one run share their first columns
    tied = np.flatnonzero(np.r_[tie, False] | np.r_[False, tie])
    keys = np.concatenate([np.asarray(c).reshape(len(c), -1)[order[tied]] for c in columns], axis=1)
    order[tied] = order[tied][np.lexsort(np.vstack([keys.T[::-1], run[tied]]))]
    return order


def canonical_mesh(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    """The same mesh with vertices sorted by position (then colour) and triangles sorted, for byte-stable files.

    Vertices equal in position and colour (a zero crossing exactly at a voxel, shared by its edges) are
    merged: their order, hence the triangles' indices, would otherwise follow open3d's hash-map order.
    """
    import open3d as o3d

    v = np.asarray(mesh.vertices)
    c = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else np.zeros((len(v), 0))
    order = canonical_point_order(v, c)
    rows = np.c_[v, c][order]
    first = np.r_[True, np.any(rows[1:] != rows[:-1], axis=1)] if len(v) else np.zeros(0, bool)
    rank = np.empty(len(v), np.int64)
    rank[order] = np.cumsum(first) - 1
    order = order[first]
    tri = rank[np.asarray(mesh.triangles)]
    if len(tri):
        # Rotate each triangle to start at its smallest index (winding kept), then sort the rows.
        shift = np.argmin(tri, axis=1)
        tri = np.take_along_axis(tri, (shift[:, None] + np.arange(3)) % 3, axis=1)
        tri = tri[np.lexsort((tri[:, 2], tri[:, 1], tri[:, 0]))]
    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v[order]), o3d.utility.Vector3iVector(tri))
    if mesh.has_vertex_colors():
        out.vertex_colors = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_colors)[order])
    out.compute_vertex_normals()  # after sorting: the summation order, hence the bits, are fixed
    return out


def write_mesh(path: Path, mesh: o3d.geometry.TriangleMesh) -> dict:
    """Write a canonical binary PLY; returns its description for attrs and the stage summary."""
    import open3d as o3d

    mesh = canonical_mesh(mesh)
    if not o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False, compressed=False):
        raise ArtifactError(f"{path}: open3d could not write the mesh")
    v = np.asarray(mesh.vertices)
    return {"file": Path(path).name, "vertices": int(len(v)), "triangles": int(len(mesh.triangles)),
            "bounds_min": np.round(v.min(axis=0), 4).tolist(), "bounds_max": np.round(v.max(axis=0), 4).tolist()}


_PLY_MESH_HEADER = (b"ply\nformat binary_little_endian 1.0\ncomment Created by Open3D\nelement vertex %d\n"
                    b"property double x\nproperty double y\nproperty double z\nproperty double nx\n"
                    b"property double ny\nproperty double nz\nproperty uchar red\nproperty uchar green\n"
                    b"property uchar blue\nelement face %d\nproperty list uchar uint vertex_indices\nend_header\n")


def read_mesh_geometry(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(n, 3)`` float32 m and triangles ``(m, 3)`` uint32 of a mesh PLY, nothing else.

    A file :func:`write_mesh` wrote is read through a memory map, field by field (no normals, colours or float64
    copy of the whole mesh in memory); any other PLY through open3d.
    """
    with open(path, "rb") as f:
        head = f.read(1024)
    end = head.find(b"end_header\n")
    counts = [int(w) for w in head[:end].split() if w.isdigit()][:2] if end > 0 else []
    if len(counts) == 2 and head[: end + 11] == _PLY_MESH_HEADER % tuple(counts):
        vertex = np.dtype([("xyz", "<f8", (3,)), ("normal", "<f8", (3,)), ("rgb", "u1", (3,))])
        face = np.dtype([("n", "u1"), ("index", "<u4", (3,))])
        n_v, n_f = counts
        vertices = np.memmap(path, vertex, "r", offset=end + 11, shape=(n_v,))
        faces = np.memmap(path, face, "r", offset=end + 11 + n_v * vertex.itemsize, shape=(n_f,))
        return vertices["xyz"].astype(np.float32), np.ascontiguousarray(faces["index"])
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.triangles, dtype=np.uint32)


def write_points(path: Path, xyz: np.ndarray, normals: np.ndarray, colors: np.ndarray) -> dict:
    """Write surface points as a binary PLY (positions m, normals, colours) in :func:`canonical_point_order`."""
    import open3d as o3d

    order = canonical_point_order(xyz, normals, colors)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[order].astype(np.float64)))
    pcd.normals = o3d.utility.Vector3dVector(normals[order].astype(np.float64))
    pcd.colors = o3d.utility.Vector3dVector(colors[order].astype(np.float64) / 255.0)
    if not o3d.io.write_point_cloud(str(path), pcd, write_ascii=False, compressed=False):
        raise ArtifactError(f"{path}: open3d could not write the point cloud")
    return {"file": Path(path).name, "count": int(len(xyz))}


class TopDown:
    """The four top-down grids of one floor, read on access from ``self.group`` (the store's root for floor 0,
    ``floors/<id>`` for the others)."""

    group: Any

    def read(self, name: str) -> np.ndarray:
        """The grid ``name`` (``occupancy``, ``navigable``, ``color``, ``height``) as this view covers it."""
        return self.group[name][...]

    @property
    def occupancy(self) -> np.ndarray:
        """``(rows, cols)`` uint8: 0 unknown, 1 free, 2 occupied."""
        return self.read("occupancy")

    @property
    def navigable(self) -> np.ndarray:
        """``(rows, cols)`` bool."""
        return self.read("navigable")

    @property
    def color(self) -> np.ndarray:
        """``(rows, cols, 3)`` uint8 RGB of the top surface."""
        return self.read("color")

    @property
    def height(self) -> np.ndarray:
        """``(rows, cols)`` float32 metres above the floor, NaN unknown."""
        return self.read("height")


class FloorGrids(TopDown):
    """Read-only view of one floor's grids in a ``recon.zarr``: ``occupancy``, ``navigable``, ``color``, ``height``
    (read on access), ``grid`` (its :class:`GridSpec`), ``floor_z`` (world z, m), ``floor`` (its :class:`Floor`
    record), ``stats``. :meth:`window` gives a part of it."""

    def __init__(self, group, floor: Floor, grid: GridSpec, floor_z: float, stats: dict):
        self.group, self.floor, self.grid, self.floor_z, self.stats = group, floor, grid, floor_z, stats

    def window(self, window) -> "WindowGrids":
        """The cells of ``window`` (a :class:`~pipeline.region.Window` of this floor's grid)."""
        return WindowGrids(self, window)

    def tile_windows(self, window=None):
        """The stored tiles (128-cell zarr chunks) meeting ``window`` (default: the whole grid), each as the
        :class:`WindowGrids` of its cells inside the window, row-major."""
        from pipeline.region import whole

        for _, _, part in (window or whole(self.grid)).tiles(TILE):
            yield WindowGrids(self, part)


class WindowGrids(TopDown):
    """A floor's grids in a window of cells: each grid read on access holds only the window's cells (zarr reads
    only the tiles it meets). ``grid`` is the window's own :class:`GridSpec` (world metres unchanged), ``cells``
    the window in the floor's grid; ``floor``, ``floor_z``, ``stats`` are the floor's."""

    def __init__(self, floor: FloorGrids, window):
        self.group, self.floor, self.floor_z, self.stats = floor.group, floor.floor, floor.floor_z, floor.stats
        self.grid, self.cells = window.grid(floor.grid), window

    def read(self, name: str) -> np.ndarray:
        return self.group[name][self.cells.slices]


@dataclass
class Recon(TopDown):
    """Read-only view of a ``recon.zarr`` for the maps, routes and evaluator stages.

    ``Recon(path)`` checks the artifact, format version and attrs (``meta``: :class:`ReconAttrs`; ``attrs`` the
    same as a plain dict); arrays are read on access. Reading the grids imports no open3d (only :meth:`mesh`).
    ``grid``, ``floor_z`` and the grids (``occupancy``, ``navigable``, ``color``, ``height``) are floor 0's (the
    only floor of a single-floor scene);
    ``floors``, :meth:`floor` and ``stairs`` give every floor of a building.
    """

    path: Path

    def __post_init__(self):
        self.path = Path(self.path)
        self.group = open_group(self.path, artifact=ARTIFACT)
        version = self.group.attrs.get("format_version")
        if version not in (FORMAT_VERSION, BUILDING_FORMAT_VERSION):
            raise ArtifactError(f"{self.path}: format_version {version!r}, this zipon reads {FORMAT_VERSION} and "
                                f"{BUILDING_FORMAT_VERSION}; rebuild it with: zipon run --force")
        self.attrs = dict(self.group.attrs)
        self.meta = ReconAttrs.read(self.attrs, self.path)
        self.grid = self.meta.grid.spec
        self.floor_z = self.meta.floor_z
        self.robot_radius_m = self.meta.robot_radius_m
        self.height_band_m = self.meta.height_band_m
        if version == BUILDING_FORMAT_VERSION and not self.meta.floors:
            raise ArtifactError(f"{self.path}: attrs.floors missing in a format_version {version} store; "
                                "rebuild it with: zipon run --force")
        self.floors: tuple[Floor, ...] = tuple(self.meta.floors or (
            Floor(id=0, name="floor 0", floor_z_m=self.floor_z, source="pinned" if self.meta.floor_estimated is False
                  else "surface", frames=int((self.meta.frames or {}).get("fused", 0))),))
        self.stairs: tuple[StairLink, ...] = tuple(self.meta.stairs or ())

    def floor(self, index: int = 0) -> FloorGrids:
        """Floor ``index``'s grids (``0``: the root's, as :attr:`occupancy` etc. read them)."""
        if not 0 <= index < len(self.floors):
            raise ArtifactError(f"{self.path}: no floor {index}; this scene has {len(self.floors)} "
                                f"floor{'s' if len(self.floors) != 1 else ''} (0..{len(self.floors) - 1})")
        record = self.floors[index]
        if index == 0:
            return FloorGrids(self.group, record, self.grid, self.floor_z, self.meta.stats)
        where = f"{FLOOR_GROUP}/{record.id}"
        try:
            sub = self.group[where]
        except KeyError:
            raise ArtifactError(f"{self.path}: {where} missing (floor {index} listed in attrs.floors); "
                                "rebuild it with: zipon run --force") from None
        try:
            meta = FloorGridAttrs.model_validate(dict(sub.attrs))
        except ValidationError as err:
            raise ArtifactError(f"{self.path}/{where}: attrs do not fit ({err.errors()[0]['msg']}); "
                                "rebuild it with: zipon run --force") from None
        return FloorGrids(sub, record, meta.grid.spec, meta.floor_z, meta.stats)

    def floor_of_z(self, z: np.ndarray) -> np.ndarray:
        """Index of the floor each world height ``z`` (metres, any shape) belongs to (:func:`floor_bands`)."""
        return floor_of_z(self.floors, z)

    @property
    def poses(self) -> np.ndarray:
        """``(N,4,4)`` float64 poses used for fusion (NaN where a frame was not fused)."""
        return self.group["pose"][...]

    @property
    def fused(self) -> np.ndarray:
        return self.group["fused"][...]

    def _beside(self, key: str, described: MeshAttrs | PointsAttrs | None, suffix: str) -> Path:
        name = described.file if described is not None else self.path.name.removesuffix(".zarr") + suffix
        path = self.path.parent / name
        if not path.is_file():
            raise MissingInputError(f"{path}: {key} file of {self.path} not found (rerun: zipon run --force)")
        return path

    @property
    def mesh_path(self) -> Path:
        return self._beside("mesh", self.meta.mesh, MESH_SUFFIX)

    @property
    def points_path(self) -> Path:
        return self._beside("points", self.meta.points, POINTS_SUFFIX)

    def mesh(self) -> o3d.geometry.TriangleMesh:
        import open3d as o3d

        return o3d.io.read_triangle_mesh(str(self.mesh_path))
