"""The tiled fold: chunk states spilled by tile and folded one tile at a time give the store, byte for byte, that
one accumulator over the whole floor gives (merged, filled and written in one piece), for both kinds of map, on a
floor of many tiles whose filled holes take features across tile borders; and so does a fold cache taken midway."""

from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fill import fill_unseen
from pipeline.maps.fusion import BlockPoints, FusedCells, FusedVoxels, TopDownAccumulator, VoxelAccumulator
from pipeline.maps.incremental import FoldWriter, load_fold
from pipeline.maps.spill import TileLayout, spill
from pipeline.maps.store import FORMAT_VERSION, Lattice, SemanticMap
from pipeline.maps.tilefold import fold_floor, plan_fill, tile_runs, write_floor
from pipeline.maps.writer import LayerShape, create_map, write_map
from pipeline.store import artifact_attrs

GRID = GridSpec(rows=27, cols=30, cell_size_m=0.25, origin_xy=(0.0, 6.75))
LAT = Lattice(GRID, 0.0, 0.0, 1.0, 0.25)  # 4 levels
TILE = 8  # 4 x 4 tiles, the last row and column of tiles narrower
DIM = 16
RADIUS_M = 0.5


def _chunks(kind: str, n_chunks=4, blocks=3, points=700, seed=0):
    """Accumulators of ``n_chunks`` chunks fed random blocks: cells in a sparse band (holes everywhere, so filled
    cells copy neighbours across tile borders), every level, distance weights for the voxel kind."""
    rng = np.random.default_rng(seed)
    inside = [r * GRID.cols + c for r in range(2, 25) for c in range(1, 29) if rng.random() < 0.7]
    accs = []
    for _ in range(n_chunks):
        acc = (VoxelAccumulator if kind == "cfmap" else TopDownAccumulator)(LAT, DIM)
        for _ in range(blocks):
            cell = rng.choice(inside, points)
            cell[rng.random(points) < 0.05] = -1  # not fused
            pts = BlockPoints(cell=cell, level=rng.integers(0, LAT.levels, points),
                              dist_m=rng.uniform(0.3, 4.0, points).astype(np.float32))
            feats = torch.from_numpy(rng.standard_normal((points, DIM)).astype(np.float32))
            weights = np.exp(-pts.dist_m**2 / 0.72).astype(np.float32) if kind == "cfmap" else None
            acc.add(pts, feats, weights)
        accs.append(acc)
    return accs


def _attrs(kind):
    return artifact_attrs(kind, FORMAT_VERSION, kind, "blake2b:test", encoder={"name": "test", "dim": DIM})


def _fillable():
    return np.random.default_rng(5).random((GRID.rows, GRID.cols)) < 0.8


def _in_memory(kind, accs, path: Path) -> None:
    """The map as one accumulator over the floor makes it: chunk states merged in order, filled, written whole."""
    fold = (VoxelAccumulator if kind == "cfmap" else TopDownAccumulator)(LAT, DIM)
    for acc in accs:
        fold.merge(acc.state())
    voxels = None
    if kind == "cfmap":
        voxels = FusedVoxels.from_state(fold.state(), LAT)
        cells = voxels.top_down()
    else:
        cells = FusedCells.from_state(fold.state())
    cells, _ = fill_unseen(cells, GRID, _fillable(), RADIUS_M)
    write_map(path, _attrs(kind), GRID, LAT, cells.to_store(), tile_cells=TILE,
              voxels=None if voxels is None else voxels.to_store(GRID))


def _tiled(kind, parts, path: Path, scratch: Path, **cache) -> None:
    layout = TileLayout(GRID, TILE)
    fold = fold_floor(parts, LAT, layout, DIM, scratch, "floor0", voxels=kind == "cfmap", keep_voxels=kind == "cfmap",
                      device="cpu", **cache)
    fill = plan_fill(fold, _fillable(), RADIUS_M)
    shape = LayerShape(GRID, LAT, fold.cells_observed + len(fill), DIM, None if fold.voxels is None else fold.voxels.rows)
    (writer,) = create_map(path, _attrs(kind), [shape], tile_cells=TILE)
    write_floor(writer, fold, fill)


def _files(path: Path) -> dict[str, bytes]:
    return {str(f.relative_to(path)): f.read_bytes() for f in sorted(path.rglob("*")) if f.is_file()}


@pytest.mark.parametrize("run_rows", [1, 400, 1 << 16])  # one tile at a time, a few, all at once
@pytest.mark.parametrize("kind", ["vlmap", "cfmap"])
def test_the_tiled_fold_writes_the_bytes_of_the_fold_in_memory(tmp_path, kind, run_rows):
    accs = _chunks(kind)
    _in_memory(kind, accs, tmp_path / "memory.zarr")
    layout = TileLayout(GRID, TILE)
    parts = [spill(acc, layout, tmp_path / "scratch", f"chunk{i}") for i, acc in enumerate(accs)]
    assert sum(p.nonempty().sum() for p in parts) > 4 * len(parts)  # every chunk spans many tiles
    _tiled(kind, parts, tmp_path / "tiled.zarr", tmp_path / "scratch", run_rows=run_rows)
    memory, tiled = _files(tmp_path / "memory.zarr"), _files(tmp_path / "tiled.zarr")
    assert memory.keys() == tiled.keys() and memory == tiled
    m = SemanticMap(tmp_path / "tiled.zarr")
    assert (m.count == 0).sum() > 10  # filled cells among them
    assert len(m.tile_start) == layout.n_tiles + 1 and (np.diff(m.tile_start) > 0).sum() > 9


@pytest.mark.parametrize("kind", ["vlmap", "cfmap"])
def test_a_fold_cache_taken_midway_folds_on_to_the_same_bytes(tmp_path, kind):
    accs = _chunks(kind, seed=1)
    layout = TileLayout(GRID, TILE)
    parts = [spill(acc, layout, tmp_path / "scratch", f"chunk{i}") for i, acc in enumerate(accs)]
    _tiled(kind, parts, tmp_path / "all.zarr", tmp_path / "scratch")
    cache = FoldWriter(tmp_path / "fold", [layout], DIM, top=kind == "vlmap")
    _tiled(kind, parts, tmp_path / "with-cache.zarr", tmp_path / "scratch", cache=cache.floors[0], cache_after=3,
           run_rows=300)
    cache.commit("blake2b:k", 16, ["a", "b", "c"], 48, 99)
    stored = load_fold(tmp_path / "fold", "blake2b:k", 16, [layout])
    assert stored is not None and stored.frames == 48
    _tiled(kind, [stored.states[0], parts[3]], tmp_path / "resumed.zarr", tmp_path / "scratch2")
    want = _files(tmp_path / "all.zarr")
    assert _files(tmp_path / "with-cache.zarr") == want and _files(tmp_path / "resumed.zarr") == want


def test_parts_cut_in_other_tiles_are_refused(tmp_path):
    (acc,) = _chunks("vlmap", n_chunks=1, blocks=1, points=50)
    part = spill(acc, TileLayout(GRID, 4), tmp_path, "chunk0")
    with pytest.raises(ValueError, match="other tiles"):
        fold_floor([part], LAT, TileLayout(GRID, TILE), DIM, tmp_path, "floor0", voxels=False, keep_voxels=False,
                   device="cpu")


def test_runs_cover_every_tile_with_rows_within_the_bounds():
    rows = np.array([0, 5, 3, 0, 0, 9, 1, 1, 1, 0, 20, 0])
    assert tile_runs(rows, max_rows=8, max_tiles=64) == [(1, 5), (5, 6), (6, 10), (10, 11)]  # empty tiles inside
    assert tile_runs(rows, max_rows=100, max_tiles=3) == [(1, 4), (5, 8), (8, 11)]
    assert tile_runs(rows, max_rows=1, max_tiles=64) == [(1, 2), (2, 3), (5, 6), (6, 7), (7, 8), (8, 10), (10, 11)]
    assert tile_runs(np.zeros(4, np.int64), max_rows=8) == []
