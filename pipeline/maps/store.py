"""The semantic map stores ``vlmap.zarr`` / ``cfmap.zarr`` and their reader :class:`SemanticMap`.

Format (version 1: one floor; version 2: a building of several floors, see below)::

    vlmap.zarr/ (or cfmap.zarr/)   attrs: artifact ('vlmap' | 'cfmap'), format_version, stage, params_digest,
    │                                     code_version, grid {rows, cols, cell_size_m, origin_xy, orientation},
    │                                     lattice {floor_z, min_height_m, max_height_m, level_height_m, levels, rule},
    │                                     encoder {name, version, dim, normalization, temperature, diagnostic, ...},
    │                                     weighting {sigma_m | null}, tile_cells, n_cells, n_voxels,
    │                                     frames {n_frames, fused, keyframes_only}, points_fused, cells_observed, cells_filled,
    │                                     fill_radius_m, units
    ├── top/                       the top-down map: one row per OBSERVED cell (compact, no dense cube)
    │   ├── cell       (N,)   int32    flat cell index row * cols + col; rows are in TILE-MAJOR order
    │   ├── features   (N,D)  float16  L2-normalised weighted mean feature; chunks (tile_cells^2, D)
    │   ├── weight     (N,)   float32  sum of point weights fused into the cell
    │   ├── count      (N,)   int32    points fused into the cell; 0 = filled from the nearest observed cell
    │   │                              (maps.fill_radius_m: unseen tops of tall objects)
    │   ├── level      (N,)   int16    height level of the cell's top (z = floor + min_height + level * level_height)
    │   ├── tile_start (T+1,) int64    cells of spatial tile t are rows [tile_start[t], tile_start[t+1]);
    │   │                              t = (row // tile_cells) * tiles_per_row + col // tile_cells
    │   └── index      (rows, cols) int32   row of top/* for each cell, -1 = unobserved; chunks (tile, tile)
    └── voxels/                    cfmap only (maps.cfmap_voxels): the sparse 3-D voxel map
        ├── key        (M,3)  int16    (row, col, level), ascending
        ├── features   (M,D)  float16  L2-normalised weighted mean feature
        ├── weight     (M,)   float32
        └── count      (M,)   int32

A building (``recon.zarr`` of more than one floor, :class:`~pipeline.recon.store.Recon`) gives a version 2
store: the root keeps floor 0's map exactly as above (``grid``, ``lattice``, the figures, ``top/`` and
``voxels/`` are floor 0's, so a reader of floor 0 needs nothing new), and adds::

    vlmap.zarr/ (or cfmap.zarr/)   attrs (added): floors [{id, name, floor_z_m, ceiling_z_m, source, frames}]
    │                                             (recon's floor records, lowest first)
    └── floors/                    a building only
        └── <id>/                  attrs: grid, lattice, n_cells, n_voxels, points_fused, cells_observed,
            │                             cells_filled (floor <id> >= 1, as the root's for floor 0)
            ├── top/               as the root's top/, on that floor's grid and lattice (a building only)
            └── voxels/            as the root's voxels/ (a building's cfmap only)

Floor k's map holds the points in floor k's height band (:func:`~pipeline.recon.store.floor_bands`) and,
within it, the lattice above that floor's ``floor_z``. A single-floor store is written as version 1,
byte for byte as before floors existed; :class:`SemanticMap` reads it as one floor.

Tile-major rows make each spatial tile one contiguous slice with the whole feature axis, so a
reader of one region reads only the chunks of its tiles; a query reads ``top/features`` one stored chunk at a
time (:meth:`SemanticMap.blocks`), and holds them only when they fit ``query.hold_features_mb``
(:mod:`pipeline.maps.query`), as the level-aware scorer does a cfmap's ``voxels/`` (:mod:`pipeline.maps.levels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from pipeline.errors import ArtifactError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.maps.scoring import chunked_scores
from pipeline.recon.store import Floor
from pipeline.store import ArtifactAttrs, AttrsModel, GridAttrs

FORMAT_VERSION = 1  # one floor (every store before floors existed)
BUILDING_FORMAT_VERSION = 2  # several floors: attrs.floors and a floors/ group
FLOOR_GROUP = "floors"  # floors/<id>/ holds floor <id>'s map (id >= 1; floor 0's is the root's)
ARTIFACTS = ("vlmap", "cfmap")
HEIGHT_RULE = "top-down feature = weighted mean of the points in the highest observed level of the cell"


# ----------------------------------------------------------------------------- the store's types


@dataclass(frozen=True)
class Lattice:
    """Grid cells x height levels above the floor (the height rule's voxels; ``attrs.lattice``)."""

    grid: GridSpec
    floor_z: float
    min_height_m: float
    max_height_m: float
    level_height_m: float

    @property
    def levels(self) -> int:
        return int(np.ceil((self.max_height_m - self.min_height_m) / self.level_height_m - 1e-9))

    @property
    def cells(self) -> int:
        return self.grid.rows * self.grid.cols

    def level_z(self, level: np.ndarray) -> np.ndarray:
        """World z (metres) of the bottom of height ``level``."""
        return self.floor_z + self.min_height_m + np.asarray(level, np.float32) * self.level_height_m

    def to_attrs(self) -> dict:
        return {
            "floor_z": float(self.floor_z),
            "min_height_m": float(self.min_height_m),
            "max_height_m": float(self.max_height_m),
            "level_height_m": float(self.level_height_m),
            "levels": self.levels,
            "rule": HEIGHT_RULE,
        }


@dataclass
class MapCells:
    """The top-down map as stored in ``top/`` (any row order; :func:`~pipeline.maps.writer.write_map` sorts tile-major)."""

    cell: np.ndarray  # (N,) int64 flat row * cols + col
    features: np.ndarray  # (N,D) float16/float32, L2-normalised weighted means
    weight: np.ndarray  # (N,) float32 sum of point weights
    count: np.ndarray  # (N,) int32 points fused (0 = filled from a neighbour)
    level: np.ndarray  # (N,) int16 top level


@dataclass
class MapVoxels:
    """The cfmap's sparse voxel map as stored in ``voxels/``: rows ascending by ``key``."""

    key: np.ndarray  # (M,3) int16 (row, col, level)
    features: np.ndarray  # (M,D) float16 L2-normalised weighted means
    weight: np.ndarray  # (M,) float32
    count: np.ndarray  # (M,) int32

    def __len__(self) -> int:
        return int(self.key.shape[0])


class LatticeAttrs(AttrsModel):
    floor_z: float
    min_height_m: float
    max_height_m: float
    level_height_m: float
    levels: int
    rule: str = HEIGHT_RULE

    def lattice(self, grid: GridSpec) -> Lattice:
        return Lattice(grid, self.floor_z, self.min_height_m, self.max_height_m, self.level_height_m)


class EncoderAttrs(AttrsModel):
    """``attrs.encoder``: the encoder's ``identity()`` (its own settings and weights digest are extra keys)."""

    name: str
    dim: int
    version: str | None = None
    normalization: str | None = None
    temperature: float | None = None
    diagnostic: bool = False

    def as_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


class FrameCounts(AttrsModel):
    n_frames: int
    fused: int
    keyframes_only: bool = False  # only recon's fused frames (its keyframes) were read (maps.keyframes_only)


class Weighting(AttrsModel):
    sigma_m: float | None = None


class FloorMapAttrs(AttrsModel):
    """The attrs of ``floors/<id>/`` in a building's map store."""

    grid: GridAttrs
    lattice: LatticeAttrs
    n_cells: int
    n_voxels: int = 0
    points_fused: int | None = None
    cells_observed: int | None = None
    cells_filled: int | None = None


class MapAttrs(ArtifactAttrs, FloorMapAttrs):
    """The attrs of ``vlmap.zarr`` / ``cfmap.zarr`` (the tree above): floor 0's map (:class:`FloorMapAttrs`) and
    what the whole store shares. Figures of the build are optional, so a map written by a test or a benchmark
    without a stage reads the same way."""

    encoder: EncoderAttrs
    tile_cells: int
    weighting: Weighting | None = None
    frames: FrameCounts | None = None
    pixels_in_band: int | None = None
    fill_radius_m: float | None = None
    units: dict[str, str] = {}
    floors: list[Floor] | None = None  # version 2 (a building) only


# group -> array -> (zarr dimension_names, attrs giving units and meaning), so `xarray.open_zarr(path, group="top")`
# names every axis; the dense (y, x, feature) grid in metres is `zipon.open(...)[scene].vlmap.to_xarray()`.
ARRAY_DIMS: dict[str, dict[str, tuple[tuple[str, ...], dict]]] = {
    "top": {
        "cell": (("cell",), {"units": "1", "long_name": "flat cell index row * cols + col (tile-major order)"}),
        "features": (("cell", "feature"), {"units": "1", "long_name": "L2-normalised weighted mean feature"}),
        "weight": (("cell",), {"units": "1", "long_name": "sum of point weights fused into the cell"}),
        "count": (("cell",), {"units": "points", "long_name": "points fused into the cell (0 = filled)"}),
        "level": (("cell",), {"units": "levels", "long_name": "height level of the cell's top",
                              "formula": "z = floor_z + min_height_m + level * level_height_m (attrs.lattice)"}),
        "tile_start": (("tile_edge",), {"units": "1", "long_name": "first row of each spatial tile in top/*"}),
        "index": (("row", "col"), {"units": "1", "long_name": "row of top/* for each grid cell, -1 = unobserved",
                                   "orientation": GridSpec.ORIENTATION}),
    },
    "voxels": {
        "key": (("voxel", "rcl"), {"units": "1", "long_name": "(row, col, level) of each voxel"}),
        "features": (("voxel", "feature"), {"units": "1", "long_name": "L2-normalised weighted mean feature"}),
        "weight": (("voxel",), {"units": "1", "long_name": "sum of point weights fused into the voxel"}),
        "count": (("voxel",), {"units": "points", "long_name": "points fused into the voxel"}),
    },
}


def tile_index(cell: np.ndarray, grid: GridSpec, tile_cells: int) -> np.ndarray:
    """Spatial tile ``(row // tile_cells) * tiles_per_row + col // tile_cells`` of each flat ``cell`` id."""
    row, col = np.divmod(np.asarray(cell, np.int64), grid.cols)
    return (row // tile_cells) * -(-grid.cols // tile_cells) + col // tile_cells


def tile_order(cell: np.ndarray, grid: GridSpec, tile_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Permutation putting flat ``cell`` ids in tile-major order, and the ``(T+1,)`` tile offsets."""
    n_tiles = (-(-grid.rows // tile_cells)) * -(-grid.cols // tile_cells)
    tile = tile_index(cell, grid, tile_cells)
    order = np.lexsort((cell, tile))
    start = np.searchsorted(tile[order], np.arange(n_tiles + 1), side="left").astype(np.int64)
    return order, start


class SemanticMap:
    """Read-only view of one floor of a ``vlmap.zarr`` / ``cfmap.zarr``; features are loaded once and cached (numpy:
    reading or scoring a map imports no torch).

    ``SemanticMap(path, floor=k)`` reads floor ``k`` (an index into ``floors``, lowest first; default 0, the only
    floor of a single-floor store). ``cell`` ``(N,)`` int64 flat cell ids, ``index`` ``(rows, cols)`` int32,
    :meth:`features16` ``(N,D)`` float16 (cached, as stored), :meth:`features` its float32 upcast, :meth:`dot`
    chunked float32 scores, ``grid`` :class:`GridSpec` and ``lattice`` :class:`Lattice` of that floor, ``meta`` the
    typed :class:`MapAttrs` (an upper floor's: the root's with the floor's own attrs; ``attrs`` the same as a plain
    dict), ``encoder`` its identity dict, ``floors`` every floor's record (:class:`~pipeline.recon.store.Floor`).
    """

    def __init__(self, path: str | Path, floor: int = 0):
        import zarr

        self.path = Path(path)
        if not (self.path / "zarr.json").is_file():
            raise MissingInputError(f"{self.path}: semantic map not found (build it with: zipon run --stage vlmap)")
        root = zarr.open_group(zarr.storage.LocalStore(str(self.path), read_only=True), mode="r")
        self.attrs = dict(root.attrs)
        artifact, version = self.attrs.get("artifact"), self.attrs.get("format_version")
        if artifact not in ARTIFACTS:
            raise ArtifactError(f"{self.path}: attrs.artifact is {artifact!r}, expected one of {ARTIFACTS}")
        if version not in (FORMAT_VERSION, BUILDING_FORMAT_VERSION):
            raise ArtifactError(f"{self.path}: format_version {version!r}, this zipon reads {FORMAT_VERSION} and "
                                f"{BUILDING_FORMAT_VERSION}; rebuild it with: zipon run --force --stage {artifact}")
        meta = MapAttrs.read(self.attrs, self.path)
        if version == BUILDING_FORMAT_VERSION and not meta.floors:
            raise ArtifactError(f"{self.path}: attrs.floors missing in a format_version {version} store; "
                                f"rebuild it with: zipon run --force --stage {artifact}")
        self.floors: tuple[Floor, ...] = tuple(meta.floors or (
            Floor(id=0, name="floor 0", floor_z_m=meta.lattice.floor_z),))
        if not 0 <= floor < len(self.floors):
            raise ArtifactError(f"{self.path}: no floor {floor}; this map has {len(self.floors)} "
                                f"floor{'s' if len(self.floors) != 1 else ''} (0..{len(self.floors) - 1})")
        self.floor_index, self.floor = floor, self.floors[floor]
        self.group = root
        if floor > 0:
            where = f"{FLOOR_GROUP}/{self.floor.id}"
            try:
                self.group = root[where]
            except KeyError:
                raise ArtifactError(f"{self.path}: {where} missing (floor {floor} listed in attrs.floors); "
                                    f"rebuild it with: zipon run --force --stage {artifact}") from None
            try:
                own = FloorMapAttrs.model_validate(dict(self.group.attrs))
            except ValidationError as err:
                raise ArtifactError(f"{self.path}/{where}: attrs do not fit ({err.errors()[0]['msg']}); "
                                    f"rebuild it with: zipon run --force --stage {artifact}") from None
            self.attrs = {**self.attrs, **own.model_dump(mode="json", exclude_none=True)}
            meta = MapAttrs.read(self.attrs, self.path)
        self.meta = meta
        self.artifact = self.meta.artifact
        self.grid = self.meta.grid.spec
        self.lattice = self.meta.lattice.lattice(self.grid)
        self.encoder = self.meta.encoder.as_dict()
        self.tile_cells = self.meta.tile_cells
        self._features: np.ndarray | None = None
        self._index: np.ndarray | None = None

    def floor_map(self, floor: int) -> "SemanticMap":
        """The same store's floor ``floor`` (this reader when it is that floor)."""
        return self if floor == self.floor_index else SemanticMap(self.path, floor)

    @property
    def n_cells(self) -> int:
        return int(self.meta.n_cells)

    @cached_property
    def cell(self) -> np.ndarray:
        """``(N,)`` int64 flat cell ids ``row * cols + col`` of the observed cells, tile-major (read on first use: a
        reader of a region needs only its tiles', :meth:`blocks`)."""
        return self.group["top"]["cell"][...].astype(np.int64)

    # read on first use (a query needs none of them)
    @cached_property
    def weight(self) -> np.ndarray:
        """``(N,)`` float32 sum of point weights fused into each cell."""
        return self.group["top"]["weight"][...]

    @cached_property
    def count(self) -> np.ndarray:
        """``(N,)`` int32 points fused into each cell (0 = filled from a neighbour)."""
        return self.group["top"]["count"][...]

    @cached_property
    def level(self) -> np.ndarray:
        """``(N,)`` int16 height level of each cell's top."""
        return self.group["top"]["level"][...]

    @cached_property
    def tile_start(self) -> np.ndarray:
        """``(T+1,)`` int64 first row of each spatial tile."""
        return self.group["top"]["tile_start"][...]

    @property
    def dim(self) -> int:
        return int(self.group["top"]["features"].shape[1])

    @property
    def index(self) -> np.ndarray:
        """``(rows, cols)`` int32 row of each cell in the compact arrays, -1 = unobserved."""
        if self._index is None:
            self._index = self.group["top"]["index"][...]
        return self._index

    def observed(self) -> np.ndarray:
        """``(rows, cols)`` bool: cells with a feature."""
        return self.index >= 0

    def features(self) -> np.ndarray:
        """``(N,D)`` float32 unit-norm features of the observed cells (a fresh upcast of :meth:`features16`).

        Not cached: a full fp32 copy is 737 MB for a 600x600x512 map. Callers that score many
        queries should keep :meth:`features16` and use :meth:`dot` (upcast per chunk).
        """
        return self.features16().astype(np.float32)

    def features16(self) -> np.ndarray:
        """``(N,D)`` float16 unit-norm features as stored (cached; half the memory of fp32)."""
        if self._features is None:
            self._features = np.ascontiguousarray(self.group["top"]["features"][...])
        return self._features

    def dot(self, text: np.ndarray, rows: np.ndarray | None = None, chunk_rows: int = 4096) -> np.ndarray:
        """``(N,T)`` (or ``(len(rows),T)``) float32 scores ``features @ text.T`` for ``text`` ``(T,D)`` or ``(D,)``,
        upcasting ``chunk_rows`` rows of the fp16 features at a time (:func:`~pipeline.maps.scoring.chunked_scores`)."""
        text = np.asarray(text, np.float32)
        t = text[None] if text.ndim == 1 else text
        f = self.features16()
        if rows is not None:
            f = f[np.asarray(rows, np.int64)]
        out = chunked_scores(f, t, chunk_rows)
        return out[:, 0] if text.ndim == 1 else out

    @property
    def has_voxels(self) -> bool:
        """True for a cfmap that stores its sparse voxel map (level-aware queries: :mod:`pipeline.maps.levels`)."""
        return "voxels" in self.group

    def tile_rows(self, tile_row: int, tile_col: int) -> tuple[int, int]:
        """Rows ``[s, e)`` of ``top/*`` holding spatial tile (``tile_row``, ``tile_col``)."""
        t = tile_row * -(-self.grid.cols // self.tile_cells) + tile_col
        return int(self.tile_start[t]), int(self.tile_start[t + 1])

    def tile(self, tile_row: int, tile_col: int) -> tuple[np.ndarray, np.ndarray]:
        """Cells ``(n,)`` int64 and features ``(n,D)`` float16 of one spatial tile (reads only its chunks)."""
        s, e = self.tile_rows(tile_row, tile_col)
        return self.read_rows(s, e)

    def read_rows(self, start: int, end: int) -> tuple[np.ndarray, np.ndarray]:
        """Cells ``(n,)`` int64 and features ``(n,D)`` float16 of rows ``[start, end)`` of ``top/*``: from the
        cached features when :meth:`features16` was called, else only the chunks those rows meet."""
        top = self.group["top"]
        cells = self.cell[start:end] if "cell" in self.__dict__ else top["cell"][start:end].astype(np.int64)
        feats = self._features[start:end] if self._features is not None else top["features"][start:end]
        return cells, feats

    def row_ranges(self, window=None) -> list[tuple[int, int]]:
        """Rows ``[s, e)`` of ``top/*`` holding the stored tiles that meet ``window`` (a
        :class:`~pipeline.region.Window`; default: the whole grid), merged where contiguous: the tiles of one tile
        row of the window are one range (rows are tile-major), the whole grid is ``[(0, N)]``."""
        from pipeline.region import whole

        window = window or whole(self.grid)
        tile = self.tile_cells
        ranges: list[tuple[int, int]] = []
        for tr in range(window.r0 // tile, -(-window.r1 // tile)):
            s = self.tile_rows(tr, window.c0 // tile)[0]
            e = self.tile_rows(tr, -(-window.c1 // tile) - 1)[1]
            if e <= s:
                continue
            if ranges and ranges[-1][1] == s:
                ranges[-1] = (ranges[-1][0], e)
            else:
                ranges.append((s, e))
        return ranges

    def blocks(self, window=None):
        """``(rows, cells, features)`` of the observed cells in ``window`` (a :class:`~pipeline.region.Window`;
        default: the whole grid), one block at a time: ``rows`` ``(n,)`` int64 ascending rows of ``top/*``,
        ``cells`` ``(n,)`` int64 flat ids, ``features`` ``(n,D)`` float16. Blocks are the stored feature chunks
        (``tile_cells``² rows, whole tiles' cells) cut to the tiles the window meets (:meth:`row_ranges`), so each
        chunk is read once per tile row of the window, only those chunks are read, and memory is one chunk's
        features, whatever the map's size."""
        from pipeline.region import whole

        every = whole(self.grid)
        window = window or every
        chunk = int(self.group["top"]["features"].chunks[0]) if self._features is None else 1 << 30
        for s, e in self.row_ranges(window):
            cuts = [s, *range((s // chunk + 1) * chunk, e, chunk), e]  # at the chunks' edges
            for a, b in zip(cuts[:-1], cuts[1:]):
                cells, feats = self.read_rows(a, b)
                rows = np.arange(a, b, dtype=np.int64)
                if window != every:  # the cells inside the window only
                    keep = window.contains(*np.divmod(cells, self.grid.cols))
                    rows, cells, feats = rows[keep], cells[keep], feats[keep]
                if len(rows):
                    yield rows, cells, feats

    def index_in(self, window) -> np.ndarray:
        """``(h, w)`` int32 rows of ``top/*`` for the cells of ``window`` (a :class:`~pipeline.region.Window`), -1 =
        unobserved; reads only the index chunks the window meets."""
        if self._index is not None:
            return self._index[window.slices]
        return self.group["top"]["index"][window.slices]

    def rows_of(self, name: str, rows: np.ndarray) -> np.ndarray:
        """``top/<name>`` at the given rows (any order, repeats allowed): from the cache when held, else only the
        chunks holding them."""
        rows = np.asarray(rows, np.int64)
        if name == "features" and self._features is not None:
            return self._features[rows]
        if name in self.__dict__:  # a cached_property already read (weight, count, level, cell)
            return self.__dict__[name][rows]
        if not len(rows):
            arr = self.group["top"][name]
            return np.zeros((0, *arr.shape[1:]), arr.dtype)
        unique, inverse = np.unique(rows, return_inverse=True)
        return self.group["top"][name].get_orthogonal_selection(unique)[inverse]

    def features_at(self, rc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Features ``(K,D)`` float32 at ``(K,2)`` (row, col) cells and a ``(K,)`` observed mask (zeros elsewhere);
        reads only the index and feature chunks holding those cells."""
        rc = np.asarray(rc, np.int64).reshape(-1, 2)
        inside = self.grid.inside(rc)
        rows = np.full(len(rc), -1, np.int64)
        if self._index is not None:
            rows[inside] = self._index[rc[inside, 0], rc[inside, 1]]
        elif inside.any():
            rows[inside] = self.group["top"]["index"].get_coordinate_selection((rc[inside, 0], rc[inside, 1]))
        ok = rows >= 0
        out = np.zeros((len(rc), self.dim), np.float32)
        out[ok] = self.rows_of("features", rows[ok])
        return out, ok

    def voxels(self) -> MapVoxels | None:
        """The cfmap's sparse voxel map (:class:`MapVoxels`), or None when the map stores none."""
        if "voxels" not in self.group:
            return None
        vx = self.group["voxels"]
        return MapVoxels(**{name: vx[name][...] for name in ("key", "features", "weight", "count")})
