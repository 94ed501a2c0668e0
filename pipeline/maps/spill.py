"""Rows kept on disk in spatial-tile order: a map build's scratch and its fold cache.

A map build's memory is bounded by one chunk of frames and one tile of the store (``maps.tile_cells``), never
by the floor's area: each chunk's :class:`~pipeline.maps.fusion.FusionState` leaves its accumulator split by
tile (:func:`spill`), and the fold (:mod:`pipeline.maps.tilefold`) reads one tile of every chunk at a time.
The same files hold what a fold finishes per tile (its cells and voxels) and the fold cache
(:mod:`pipeline.maps.incremental`).

One :class:`TileRows` is a set of files ``<name>.*`` in a folder::

    <name>.tiles.npy       (T+1,) int64   rows of tile t are [tiles[t], tiles[t+1]) of every column
    <name>.<column>.bin    (rows, *tail)  raw rows of one column, tile after tile (the order they came in)
    <name>.json            {"format", "grid": [rows, cols], "tile_cells", "rows",
                            "columns": {column: [dtype, tail]}}; written last: a set without it is unfinished

A tile is a square of ``tile_cells`` cells of the grid, numbered row-major (:func:`~pipeline.maps.store.tile_index`).
Keys of a state are flat cells (a top-down state's) or ``level * cells + cell`` (a voxel state's); both find
their tile from ``key % cells``. :meth:`TileLayout.local` numbers the keys of a run of consecutive tiles within
their squares alone, so the run folds in a small accumulator.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fusion import FusionState
from pipeline.maps.store import Lattice, tile_index

FORMAT = 1
STATE_COLUMNS = ("keys", "sum", "weight", "count", "top")  # a FusionState's fields, in this order
SPILL_ROWS = 1 << 15  # rows gathered from an accumulator per write (64 MB of sums at D = 512)


@dataclass(frozen=True)
class TileLayout:
    """The store's spatial tiles of ``grid`` (squares of ``tile_cells`` cells; those on the far edges smaller)."""

    grid: GridSpec
    tile_cells: int

    @property
    def tiles_per_row(self) -> int:
        return -(-self.grid.cols // self.tile_cells)

    @property
    def n_tiles(self) -> int:
        return -(-self.grid.rows // self.tile_cells) * self.tiles_per_row

    @property
    def cells(self) -> int:
        return self.grid.rows * self.grid.cols

    def tile_of(self, keys: np.ndarray) -> np.ndarray:
        """``(n,)`` int64 tile of each key (a flat cell, or ``level * cells + cell``)."""
        return tile_index(np.asarray(keys, np.int64) % self.cells, self.grid, self.tile_cells)

    def local(self, keys: np.ndarray, first: int, stop: int) -> np.ndarray:
        """Keys of tiles ``[first, stop)`` numbered within them: ``(level * (stop - first) + tile - first) *
        tile_cells^2 + local row * tile_cells + local col``, the keys of :meth:`fold_lattice`'s squares stacked."""
        level, cell = np.divmod(np.asarray(keys, np.int64), self.cells)
        row, col = np.divmod(cell, self.grid.cols)
        tc = self.tile_cells
        tile = (row // tc) * self.tiles_per_row + col // tc
        return ((level * (stop - first) + tile - first) * tc + row % tc) * tc + col % tc

    def global_keys(self, local: np.ndarray, first: int, stop: int) -> np.ndarray:
        """The inverse of :meth:`local`."""
        tc = self.tile_cells
        rest, col = np.divmod(np.asarray(local, np.int64), tc)
        rest, row = np.divmod(rest, tc)
        level, tile = np.divmod(rest, stop - first)
        tile_row, tile_col = np.divmod(tile + first, self.tiles_per_row)
        return level * self.cells + (tile_row * tc + row) * self.grid.cols + tile_col * tc + col

    def fold_lattice(self, lattice: Lattice, n_tiles: int) -> Lattice:
        """A lattice whose keys are :meth:`local`'s for ``n_tiles`` tiles (their squares stacked), the height levels
        of ``lattice``."""
        squares = GridSpec(n_tiles * self.tile_cells, self.tile_cells, self.grid.cell_size_m, self.grid.origin_xy)
        return Lattice(squares, lattice.floor_z, lattice.min_height_m, lattice.max_height_m, lattice.level_height_m)


class TileRowsWriter:
    """Writes a :class:`TileRows`: rows come in blocks, each row with its tile, tiles never decreasing."""

    def __init__(self, folder: Path, name: str, layout: TileLayout, columns: dict[str, tuple[str, tuple[int, ...]]]):
        self.folder, self.name, self.layout = Path(folder), name, layout
        self.columns = {c: (np.dtype(dtype), tuple(tail)) for c, (dtype, tail) in columns.items()}
        self.folder.mkdir(parents=True, exist_ok=True)
        (self.folder / f"{name}.json").unlink(missing_ok=True)  # unfinished until close() writes it again
        self._files = {c: open(self.folder / f"{name}.{c}.bin", "wb") for c in self.columns}
        self._counts = np.zeros(layout.n_tiles, np.int64)
        self._last = 0

    def append(self, tiles: np.ndarray, **columns: np.ndarray) -> None:
        """Rows ``(n,)`` of tiles ``tiles`` (non-decreasing, not before the last block's) and one array per column."""
        tiles = np.asarray(tiles, np.int64)
        if not len(tiles):
            return
        if tiles[0] < self._last or (np.diff(tiles) < 0).any():
            raise ValueError(f"{self.folder / self.name}: rows must come in tile order")
        if set(columns) != set(self.columns):
            raise ValueError(f"{self.folder / self.name}: columns {sorted(columns)}, expected {sorted(self.columns)}")
        for c, (dtype, tail) in self.columns.items():
            a = columns[c].numpy() if isinstance(columns[c], torch.Tensor) else np.asarray(columns[c])
            if a.shape != (len(tiles),) + tail:
                raise ValueError(f"{self.folder / self.name}: column {c} of shape {a.shape}, expected "
                                 f"{(len(tiles),) + tail}")
            np.ascontiguousarray(a, dtype=dtype).tofile(self._files[c])
        self._counts += np.bincount(tiles, minlength=len(self._counts))
        self._last = int(tiles[-1])

    def close(self) -> "TileRows":
        for f in self._files.values():
            f.close()
        tiles = np.r_[0, np.cumsum(self._counts)].astype(np.int64)
        np.save(self.folder / f"{self.name}.tiles.npy", tiles)
        meta = {"format": FORMAT, "grid": [self.layout.grid.rows, self.layout.grid.cols],
                "tile_cells": self.layout.tile_cells, "rows": int(tiles[-1]),
                "columns": {c: [dtype.str, list(tail)] for c, (dtype, tail) in self.columns.items()}}
        (self.folder / f"{self.name}.json").write_text(json.dumps(meta))
        return TileRows(self.folder, self.name)

    def abort(self) -> None:
        for f in self._files.values():
            f.close()


class TileRows:
    """A finished set of rows on disk (the module doc), read one tile, one span of tiles or some rows at a time.

    Every read copies the rows it asks for into memory; no file stays mapped. Pages a process touches through a map
    count in its resident memory until the map is closed (the system drops them only under pressure), so maps held
    open over a build's spilled chunks made its peak grow with everything it had read: the chunks' sums, then the
    folded map (:mod:`pipeline.maps.tilefold`). Read this way, the files' pages stay in the page cache, not in the
    process."""

    def __init__(self, folder: Path, name: str):
        self.folder, self.name = Path(folder), name
        meta = json.loads((self.folder / f"{name}.json").read_text())
        if meta.get("format") != FORMAT:
            raise ValueError(f"{self.folder / name}: format {meta.get('format')!r}, expected {FORMAT}")
        self.grid_shape, self.tile_cells, self.rows = tuple(meta["grid"]), int(meta["tile_cells"]), int(meta["rows"])
        self.tiles = np.load(self.folder / f"{name}.tiles.npy")
        if len(self.tiles) < 1 or int(self.tiles[-1]) != self.rows:
            raise ValueError(f"{self.folder / name}: tile offsets end at {self.tiles[-1:]}, expected {self.rows} rows")
        self.columns: dict[str, tuple[np.dtype, tuple[int, ...]]] = {}  # column: (dtype, shape of a row)
        for c, (dtype, tail) in meta["columns"].items():
            path = self._path(c)
            shape = (self.rows,) + tuple(tail)
            if path.stat().st_size != int(np.prod(shape)) * np.dtype(dtype).itemsize:
                raise ValueError(f"{path}: {path.stat().st_size} bytes, expected {shape} {dtype}")
            self.columns[c] = (np.dtype(dtype), tuple(tail))

    def _path(self, column: str) -> Path:
        return self.folder / f"{self.name}.{column}.bin"

    @property
    def nbytes(self) -> int:
        """Bytes of every column on disk."""
        return sum(self.rows * dtype.itemsize * int(np.prod(tail)) for dtype, tail in self.columns.values())

    def fits(self, layout: TileLayout) -> bool:
        """Whether these rows were cut by ``layout``'s tiles."""
        return self.grid_shape == (layout.grid.rows, layout.grid.cols) and self.tile_cells == layout.tile_cells

    def nonempty(self) -> np.ndarray:
        """``(T,)`` bool: tiles holding rows."""
        return np.diff(self.tiles) > 0

    def read(self, column: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows ``[start, stop)`` of ``column`` (default: all of them), read into a new array."""
        dtype, tail = self.columns[column]
        stop = self.rows if stop is None else stop
        per_row = int(np.prod(tail))
        with open(self._path(column), "rb") as f:
            f.seek(start * per_row * dtype.itemsize)
            data = np.fromfile(f, dtype=dtype, count=(stop - start) * per_row)
        if data.size != (stop - start) * per_row:  # the file shrank since it was opened
            raise ValueError(f"{self._path(column)}: rows [{start}, {stop}) of {self.rows} asked, the file holds "
                             f"{start + data.size // max(per_row, 1)} rows")
        return data.reshape((stop - start,) + tail)

    def take(self, column: str, rows: np.ndarray) -> np.ndarray:
        """Rows ``rows`` (any order, repeats allowed) of ``column``, read into a new array through a map that is
        closed before returning."""
        dtype, tail = self.columns[column]
        rows = np.asarray(rows, np.int64)
        if not len(rows):
            return np.zeros((0,) + tail, dtype)
        mapped = np.memmap(self._path(column), dtype=dtype, mode="r", shape=(self.rows,) + tail)
        return mapped[rows]  # a copy; the map is closed as its last reference goes

    def span(self, first: int, stop: int | None = None) -> dict[str, np.ndarray]:
        """Every column's rows of tiles ``[first, stop)`` (default: tile ``first`` alone), read into memory."""
        s, e = int(self.tiles[first]), int(self.tiles[first + 1 if stop is None else stop])
        return {c: self.read(c, s, e) for c in self.columns}

    def state(self, first: int, stop: int | None = None) -> FusionState:
        """The rows of tiles ``[first, stop)`` (default: tile ``first``) of a spilled :class:`FusionState`."""
        rows = self.span(first, stop)
        top = rows.get("top")
        return FusionState(keys=rows["keys"], sum=torch.from_numpy(rows["sum"]),
                           weight=torch.from_numpy(rows["weight"]), count=torch.from_numpy(rows["count"]),
                           top=None if top is None else torch.from_numpy(top))


def state_columns(dim: int, top: bool) -> dict[str, tuple[str, tuple[int, ...]]]:
    """The columns of a spilled :class:`FusionState` of ``dim`` features (``top``: a top-down state's)."""
    columns = {"keys": ("<i8", ()), "sum": ("<f4", (dim,)), "weight": ("<f8", ()), "count": ("<i8", ())}
    return {**columns, "top": ("<i8", ())} if top else columns


def spill(acc, layout: TileLayout, folder: Path, name: str) -> TileRows:
    """Write accumulator ``acc``'s content (:class:`~pipeline.maps.fusion.TopDownAccumulator` or
    :class:`~pipeline.maps.fusion.VoxelAccumulator`) split by ``layout``'s tiles, keys ascending within a tile,
    gathering :data:`SPILL_ROWS` rows at a time (never a copy of the whole state)."""
    keys, slots = acc.observed()
    tiles = layout.tile_of(keys)
    order = np.argsort(tiles, kind="stable")
    writer = TileRowsWriter(folder, name, layout, state_columns(acc.dim, top=acc.keeps_top))
    try:
        for s in range(0, len(order), SPILL_ROWS):
            o = order[s : s + SPILL_ROWS]
            part = acc.rows(keys[o], slots[o])
            writer.append(tiles[o], **{c: getattr(part, c) for c in writer.columns})
    except BaseException:
        writer.abort()
        raise
    return writer.close()


def write_state(writer: TileRowsWriter, state: FusionState) -> None:
    """Append ``state`` (keys of tiles at or after the writer's last) to a writer of :func:`state_columns`, split
    by tile, keys ascending within a tile."""
    tiles = writer.layout.tile_of(state.keys)
    order = np.lexsort((state.keys, tiles))
    index = torch.from_numpy(order)
    writer.append(tiles[order], **{c: getattr(state, c)[order if c == "keys" else index] for c in writer.columns})
