"""Writing a map store row block by row block: its groups and attrs first, then each floor's rows in store order.

:func:`create_map` checks and writes the attrs of a ``vlmap.zarr`` / ``cfmap.zarr`` (the tree in
:mod:`pipeline.maps.store`) from each floor's :class:`LayerShape` (how many cells and voxels it will hold) and
returns one :class:`LayerWriter` per floor. A writer takes the floor's top-down rows in tile-major order and its
voxel rows in key order, in blocks of any size, and writes them to zarr a whole chunk at a time: the chunks hold
the same values as an array written in one piece, so the store's bytes do not depend on the blocks. Memory: one
block and less than one chunk per array, plus the ``(rows, cols)`` int32 index (written last). A build that
folds its map one spatial tile at a time (:mod:`pipeline.maps.tilefold`) streams it here; :func:`write_map`
writes a map held in memory (tests, benchmarks) through the same writers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.maps.store import (ARRAY_DIMS, BUILDING_FORMAT_VERSION, FLOOR_GROUP, FloorMapAttrs, Lattice, MapAttrs,
                                 MapCells, MapVoxels, tile_index, tile_order)
from pipeline.recon.store import Floor
from pipeline.store import compressor, new_group

if TYPE_CHECKING:
    import zarr

UNITS = {"features": "unit L2 norm", "weight": "sum of point weights", "distance": "metres"}


@dataclass(frozen=True)
class LayerShape:
    """What one floor's group says before its rows are written: grid, lattice, ``n_cells`` top-down rows of ``dim``
    features, ``n_voxels`` voxel rows (None: no ``voxels/`` group), and for a floor above the first its record
    and figures (``points_fused``, ``cells_observed``, ``cells_filled``)."""

    grid: GridSpec
    lattice: Lattice
    n_cells: int
    dim: int
    n_voxels: int | None = None
    floor: Floor | None = None
    figures: dict[str, Any] = field(default_factory=dict)


def create_map(path: Path, attrs: dict, layers: list[LayerShape], *, tile_cells: int,
               floors: list[Floor] | None = None) -> list["LayerWriter"]:
    """Create the map store at ``path`` (must not exist) with its attrs and one group per floor; return a writer
    per layer (``layers[0]``: floor 0's, the root's; then one per floor above it, with its ``floor``).

    ``attrs`` = ``artifact_attrs(...)`` + the figures, checked against :class:`MapAttrs` before anything is
    written. ``floors`` (recon's records) of more than one floor make a building (version 2, ``floors/<id>/``);
    otherwise the store is version 1 and ``layers`` holds floor 0 only."""
    building = floors is not None and len(floors) > 1
    upper = layers[1:] if building else []
    if building and [f.id for f in floors[1:]] != [layer.floor.id for layer in upper]:
        raise ValueError(f"{path}: floors {[f.id for f in floors]} need one upper layer per floor above the first, "
                         f"got {[None if layer.floor is None else layer.floor.id for layer in upper]}")
    extra = {}
    if building:
        extra = {"format_version": BUILDING_FORMAT_VERSION, "floors": [f.model_dump(mode="json") for f in floors]}
    first = layers[0]
    g = new_group(path, MapAttrs.checked(
        {**attrs, "grid": first.grid.to_attrs(), "lattice": first.lattice.to_attrs(), "tile_cells": tile_cells,
         "n_cells": first.n_cells, "n_voxels": first.n_voxels or 0, "units": UNITS, **extra}, path))
    writers = [LayerWriter(g, first, tile_cells)]
    for layer in upper:
        sub = g.require_group(FLOOR_GROUP).create_group(str(layer.floor.id))
        floor_attrs = FloorMapAttrs.model_validate(
            {"grid": layer.grid.to_attrs(), "lattice": layer.lattice.to_attrs(), "n_cells": layer.n_cells,
             "n_voxels": layer.n_voxels or 0, **layer.figures})
        sub.attrs.update(floor_attrs.model_dump(mode="json", exclude_none=True))
        writers.append(LayerWriter(sub, layer, tile_cells))
    return writers


class _Column:
    """One zarr array filled from the front in blocks; only whole chunks are written until :meth:`close`."""

    def __init__(self, array: "zarr.Array", dtype: np.dtype):
        self.array, self.dtype = array, np.dtype(dtype)
        self.chunk_rows = int(array.chunks[0])
        self.written = 0
        self.pending: list[np.ndarray] = []
        self.n_pending = 0

    def add(self, block: np.ndarray) -> None:
        block = np.asarray(block).astype(self.dtype, copy=False)
        if self.written + self.n_pending + len(block) > self.array.shape[0]:
            raise ValueError(f"{self.array.path}: more than the {self.array.shape[0]} rows announced")
        self.pending.append(block)
        self.n_pending += len(block)
        if self.n_pending >= self.chunk_rows:
            self._flush(self.n_pending - self.n_pending % self.chunk_rows)

    def _flush(self, n: int) -> None:
        data = self.pending[0] if len(self.pending) == 1 else np.concatenate(self.pending)
        if n:
            self.array[self.written : self.written + n] = data[:n]
        self.written += n
        rest = data[n:]
        self.pending, self.n_pending = ([rest] if len(rest) else []), len(rest)

    def close(self) -> None:
        if self.n_pending:
            self._flush(self.n_pending)
        if self.written != self.array.shape[0]:
            raise ValueError(f"{self.array.path}: {self.written} rows written of the {self.array.shape[0]} announced")


class LayerWriter:
    """One floor's ``top/`` (and ``voxels/``) arrays, filled in store order (see the module doc)."""

    def __init__(self, g: "zarr.Group", shape: LayerShape, tile_cells: int):
        self.g, self.shape, self.tile_cells = g, shape, tile_cells
        self.chunk = max(tile_cells * tile_cells, 1)
        self.compressor = compressor(3, shuffle="shuffle")
        top = g.create_group("top")
        n, dim = shape.n_cells, max(shape.dim, 1)
        self.top = {name: _Column(self._array(top, name, (n,) + tail, (self.chunk,) + tail, dtype), dtype)
                    for name, tail, dtype in (("cell", (), np.int32), ("features", (dim,), np.float16),
                                              ("weight", (), np.float32), ("count", (), np.int32),
                                              ("level", (), np.int16))}
        self.voxels = None
        if shape.n_voxels is not None:
            vx, m = g.create_group("voxels"), shape.n_voxels
            self.voxels = {name: _Column(self._array(vx, name, (m,) + tail, (self.chunk,) + tail, dtype), dtype)
                           for name, tail, dtype in (("key", (3,), np.int16), ("features", (dim,), np.float16),
                                                     ("weight", (), np.float32), ("count", (), np.int32))}
        self.index = np.full(shape.grid.rows * shape.grid.cols, -1, dtype=np.int32)
        self.tile_rows = np.zeros(-(-shape.grid.rows // tile_cells) * -(-shape.grid.cols // tile_cells), np.int64)
        self.cells_added = 0
        self.last_tile = self.last_cell = -1

    def _array(self, group, name, shape, chunks, dtype) -> "zarr.Array":
        dims, meaning = ARRAY_DIMS[group.basename][name]
        a = group.create_array(name, shape=shape, chunks=chunks, dtype=dtype, compressors=self.compressor,
                               dimension_names=dims)
        a.attrs.update(meaning)
        return a

    def add_cells(self, cell: np.ndarray, features: np.ndarray, weight: np.ndarray, count: np.ndarray,
                  level: np.ndarray) -> None:
        """The next ``top/`` rows: flat cells ``(n,)`` in tile-major order (ascending within a tile) and their
        ``features`` ``(n,D)`` (cast to float16), ``weight``, ``count`` and ``level``."""
        cell = np.asarray(cell, np.int64)
        if not len(cell):
            return
        tile = tile_index(cell, self.shape.grid, self.tile_cells)
        order = np.stack([np.r_[self.last_tile, tile], np.r_[self.last_cell, cell]])
        step = np.diff(order, axis=1)
        if ((step[0] < 0) | ((step[0] == 0) & (step[1] <= 0))).any():
            raise ValueError(f"{self.g.path}/top: cells must come in tile-major order, each once")
        for name, block in (("cell", cell), ("features", features), ("weight", weight), ("count", count),
                            ("level", level)):
            self.top[name].add(block)
        self.index[cell] = np.arange(self.cells_added, self.cells_added + len(cell), dtype=np.int32)
        self.tile_rows += np.bincount(tile, minlength=len(self.tile_rows))
        self.cells_added += len(cell)
        self.last_tile, self.last_cell = int(tile[-1]), int(cell[-1])

    def add_voxels(self, key: np.ndarray, features: np.ndarray, weight: np.ndarray, count: np.ndarray) -> None:
        """The next ``voxels/`` rows: ``key`` ``(m,3)`` (row, col, level) ascending, and their features, weight
        and count."""
        if self.voxels is None:
            raise ValueError(f"{self.g.path}: this layer was created without voxels")
        for name, block in (("key", key), ("features", features), ("weight", weight), ("count", count)):
            self.voxels[name].add(block)

    def close(self) -> None:
        """Write what is pending, ``top/tile_start`` and ``top/index``; every announced row must have come."""
        for column in (*self.top.values(), *(self.voxels or {}).values()):
            column.close()
        top = self.g["top"]
        start = np.r_[0, np.cumsum(self.tile_rows)].astype(np.int64)
        self._array(top, "tile_start", start.shape, start.shape, np.int64)[...] = start
        grid = self.shape.grid
        self._array(top, "index", (grid.rows, grid.cols), (self.tile_cells, self.tile_cells),
                    np.int32)[...] = self.index.reshape(grid.rows, grid.cols)


@dataclass
class FloorLayer:
    """One upper floor's map in a building's store (``floors/<id>/``): as the root's arguments of :func:`write_map`
    for floor 0, plus the floor's figures (``points_fused``, ``cells_observed``, ``cells_filled``)."""

    floor: Floor
    grid: GridSpec
    lattice: Lattice
    cells: MapCells
    voxels: MapVoxels | None = None
    figures: dict[str, Any] = field(default_factory=dict)


def write_map(
    path: Path,
    attrs: dict,
    grid: GridSpec,
    lattice: Lattice,
    cells: MapCells,
    *,
    tile_cells: int,
    voxels: MapVoxels | None = None,
    floors: list[Floor] | None = None,
    upper: list[FloorLayer] = (),
) -> zarr.Group:
    """Write a map store at ``path`` (must not exist). ``attrs`` = ``artifact_attrs(...)`` + extras, checked
    against :class:`MapAttrs` before anything is written. ``grid``, ``lattice``, ``cells``, ``voxels``: floor 0's
    map (a single floor's). ``floors`` (recon's records) of more than one floor with ``upper`` (one
    :class:`FloorLayer` per floor above the first) write a building (version 2, the module doc); otherwise the
    store is version 1 exactly as before floors existed."""
    def shape(cells: MapCells, voxels: MapVoxels | None, **kw) -> LayerShape:
        features = np.asarray(cells.features)
        return LayerShape(kw.pop("grid"), kw.pop("lattice"), len(cells.cell),
                          int(features.shape[1]) if features.ndim == 2 else 0,
                          None if voxels is None else len(voxels), **kw)

    building = floors is not None and len(floors) > 1
    layers = [(cells, voxels, shape(cells, voxels, grid=grid, lattice=lattice))]
    layers += [(layer.cells, layer.voxels, shape(layer.cells, layer.voxels, grid=layer.grid, lattice=layer.lattice,
                                                 floor=layer.floor, figures=layer.figures))
               for layer in (upper if building else ())]
    writers = create_map(path, attrs, [s for _, _, s in layers], tile_cells=tile_cells, floors=floors)
    for writer, (layer_cells, layer_voxels, layer_shape) in zip(writers, layers):
        order, _ = tile_order(layer_cells.cell, layer_shape.grid, tile_cells)
        writer.add_cells(layer_cells.cell[order], np.asarray(layer_cells.features)[order], layer_cells.weight[order],
                         layer_cells.count[order], layer_cells.level[order])
        if layer_voxels is not None:
            key = np.asarray(layer_voxels.key).astype(np.int16)
            o = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
            writer.add_voxels(key[o], np.asarray(layer_voxels.features)[o], np.asarray(layer_voxels.weight)[o],
                              np.asarray(layer_voxels.count)[o])
        writer.close()
    return writers[0].g
