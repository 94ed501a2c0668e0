"""Folding a floor's map a few spatial tiles at a time, and streaming it into the store: memory by the tile.

The chunks of a map build (:mod:`pipeline.maps.build`) leave their partial states on disk split by the store's
tiles (:mod:`pipeline.maps.spill`). :func:`fold_floor` then takes one run of consecutive tiles at a time
(:func:`tile_runs`: at most :data:`FOLD_ROWS` rows, or a single tile): a small accumulator over those tiles' keys
alone folds their rows of every chunk, in chunk order. Every key's rows are added in the same order, from zero,
as in one accumulator over the whole floor (:mod:`pipeline.maps.fusion`: folds are elementwise per key), so the
floats are the same bit for bit; only the memory differs (a run's rows instead of the floor's). The run's map is
finished there (unit means; the cfmap's voxels projected with the height rule) and its cells and voxels, already
float16 as stored, go back to disk in tile order.

:func:`plan_fill` then finds the cells to fill (``maps.fill_radius_m``) from the observed cells alone, which
fixes every floor's row counts before the store is created, and :func:`write_floor` streams the rows into the
store (:class:`~pipeline.maps.writer.LayerWriter`): ``top/`` tile after tile, each tile's observed and filled
cells merged, then ``voxels/`` one band of tiles (a tile row) at a time in (row, col, level) order. The store's
bytes are those of a map folded and written in one piece.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.maps.fill import fill_targets
from pipeline.maps.fusion import FusedCells, FusedVoxels, TopDownAccumulator, VoxelAccumulator
from pipeline.maps.spill import TileLayout, TileRows, TileRowsWriter, write_state
from pipeline.maps.store import Lattice
from pipeline.maps.writer import LayerWriter

CELL_COLUMNS = {"cell": ("<i8", ()), "weight": ("<f4", ()), "count": ("<i4", ()), "level": ("<i2", ())}
VOXEL_COLUMNS = {"key": ("<i2", (3,)), "weight": ("<f4", ()), "count": ("<i4", ())}
WRITE_ROWS = 1 << 15  # voxel rows gathered per block on the way to the store
FOLD_ROWS = 1 << 16  # rows (of all the chunks) a run of tiles folds at once: 128 MB of fp32 sums at D = 512
FOLD_TILES = 64  # tiles of a run at most (its slot lattice: 64 x tile_cells^2 x levels int32)


@dataclass
class FloorFold:
    """What folding one floor left on disk: its observed cells (tile-major, cells ascending within a tile:
    ``cell`` int64, ``features`` float16, ``weight`` float32, ``count`` int32, ``level`` int16) and voxels (``key``
    (row, col, level) int16, ``features``, ``weight``, ``count``; None when the map stores none), with the points
    in its sums (:attr:`~pipeline.maps.fusion.FusionState.points`)."""

    layout: TileLayout
    cells: TileRows
    voxels: TileRows | None
    points: int

    @property
    def cells_observed(self) -> int:
        return self.cells.rows


@dataclass
class FillPlan:
    """The cells one floor fills (``new_cell``, tile-major) and the row of :attr:`FloorFold.cells` each copies."""

    new_cell: np.ndarray
    source_row: np.ndarray

    def __len__(self) -> int:
        return len(self.new_cell)


def fold_floor(parts: list[TileRows], lattice: Lattice, layout: TileLayout, dim: int, scratch: Path, name: str, *,
               voxels: bool, keep_voxels: bool, device: str, cache: TileRowsWriter | None = None,
               cache_after: int = 0, run_rows: int | None = None) -> FloorFold:
    """Fold ``parts`` (one floor's spilled chunk states, in chunk order; ``voxels``: they are voxel states) one run
    of tiles at a time (:func:`tile_runs`, runs of ``run_rows`` rows at most, default :data:`FOLD_ROWS`) and write the
    finished tiles to ``scratch`` as ``<name>.cells`` (and ``<name>.voxels`` when ``keep_voxels``). With ``cache``, the
    fold of ``parts[:cache_after]`` is appended to it too (the fold cache, :mod:`pipeline.maps.incremental`)."""
    for part in parts:
        if not part.fits(layout):
            raise ValueError(f"{part.folder / part.name}: cut in other tiles than {layout}")
    accumulator = VoxelAccumulator if voxels else TopDownAccumulator
    feature = {"features": ("<f2", (dim,))}
    cells_out = TileRowsWriter(scratch, f"{name}.cells", layout, {**CELL_COLUMNS, **feature})
    voxels_out = TileRowsWriter(scratch, f"{name}.voxels", layout, {**VOXEL_COLUMNS, **feature}) if keep_voxels else None
    rows = np.zeros(layout.n_tiles, np.int64)
    for part in parts:
        rows += np.diff(part.tiles)
    points = 0
    for first, stop in tile_runs(rows, FOLD_ROWS if run_rows is None else run_rows):
        acc = accumulator(layout.fold_lattice(lattice, stop - first), dim, device=device)
        for j, part in enumerate(parts):
            if cache is not None and j == cache_after:
                write_state(cache, _global(acc.state(), layout, first, stop))
            if part.tiles[first] < part.tiles[stop]:
                state = part.state(first, stop)
                state.keys = layout.local(state.keys, first, stop)
                acc.merge(state)
        if cache is not None and cache_after == len(parts):
            write_state(cache, _global(acc.state(), layout, first, stop))
        state = _global(acc.state(), layout, first, stop)
        del acc
        points += state.points
        if voxels:
            fused = FusedVoxels.from_state(state, lattice)
            cells = fused.top_down()
            if voxels_out is not None:
                stored = fused.to_store(lattice.grid)
                tiles = layout.tile_of(fused.cell)
                o = np.argsort(tiles, kind="stable")
                voxels_out.append(tiles[o], key=stored.key[o], features=stored.features[o], weight=stored.weight[o],
                                  count=stored.count[o])
        else:
            cells = FusedCells.from_state(state)
        tiles = layout.tile_of(cells.cell)
        o = np.lexsort((cells.cell, tiles))
        cells_out.append(tiles[o], cell=cells.cell[o], features=cells.features.numpy()[o].astype(np.float16),
                         weight=cells.weight[o], count=cells.count[o], level=cells.level[o])
    return FloorFold(layout, cells_out.close(), None if voxels_out is None else voxels_out.close(), points)


def tile_runs(rows: np.ndarray, max_rows: int, max_tiles: int = FOLD_TILES) -> list[tuple[int, int]]:
    """``[first, stop)`` runs of consecutive tiles covering every tile with ``rows`` (their rows in all the parts),
    each of at most ``max_tiles`` tiles and ``max_rows`` rows (or one tile, whatever its rows): the unit a fold
    holds in memory. Runs rather than single tiles: fewer, larger tensor operations."""
    runs, t, n = [], 0, len(rows)
    while t < n:
        if not rows[t]:
            t += 1
            continue
        first, total = t, 0
        while t < n and t - first < max_tiles and (t == first or total + rows[t] <= max_rows):
            total += int(rows[t])
            t += 1
        runs.append((first, t))
    return runs


def _global(state, layout: TileLayout, first: int, stop: int):
    state.keys = layout.global_keys(state.keys, first, stop)
    return state


def plan_fill(fold: FloorFold, fillable: np.ndarray, radius_m: float) -> FillPlan:
    """The cells :func:`write_floor` fills (:func:`~pipeline.maps.fill.fill_targets`), from the observed cells
    alone (an int64 per cell: no feature is read)."""
    cell = fold.cells.read("cell")
    new_cell, source = fill_targets(cell, fold.layout.grid, fillable, radius_m)
    by_tile = np.lexsort((new_cell, fold.layout.tile_of(new_cell)))
    order = np.argsort(cell)
    return FillPlan(new_cell[by_tile], order[np.searchsorted(cell, source[by_tile], sorter=order)])


def write_floor(writer: LayerWriter, fold: FloorFold, fill: FillPlan) -> None:
    """Stream one floor's folded rows into its store layer: the cells tile after tile (each tile's observed and
    filled cells, ascending), then the voxels in (row, col, level) order, one band of tiles at a time."""
    layout, cells = fold.layout, fold.cells
    fill_tile = layout.tile_of(fill.new_cell)
    fill_start = np.searchsorted(fill_tile, np.arange(layout.n_tiles + 1))
    has_rows = cells.nonempty() | (np.diff(fill_start) > 0)
    for t in np.flatnonzero(has_rows):
        own = cells.span(int(t))
        src = fill.source_row[fill_start[t] : fill_start[t + 1]]
        n_new = len(src)
        cell = np.concatenate([own["cell"], fill.new_cell[fill_start[t] : fill_start[t + 1]]])
        order = np.argsort(cell, kind="stable")
        writer.add_cells(cell[order], np.concatenate([own["features"], cells.take("features", src)])[order],
                         np.concatenate([own["weight"], np.zeros(n_new, np.float32)])[order],
                         np.concatenate([own["count"], np.zeros(n_new, np.int32)])[order],
                         np.concatenate([own["level"], cells.take("level", src)])[order])
    if fold.voxels is not None:
        vox, per_row = fold.voxels, layout.tiles_per_row
        for first in range(0, layout.n_tiles, per_row):
            start, stop = int(vox.tiles[first]), int(vox.tiles[min(first + per_row, layout.n_tiles)])
            key = vox.read("key", start, stop)  # the band's keys; its features are read a block at a time
            order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
            for s in range(0, len(order), WRITE_ROWS):
                o = order[s : s + WRITE_ROWS]
                writer.add_voxels(key[o], *(vox.take(c, start + o) for c in ("features", "weight", "count")))
    writer.close()
