"""The store written block by block: the bytes of a store written in one piece whatever the blocks, and the checks
on what a layer is given (order, counts, voxels)."""

from pathlib import Path

import numpy as np
import pytest

from pipeline.geometry import GridSpec
from pipeline.maps.store import FORMAT_VERSION, Lattice, MapCells, MapVoxels, SemanticMap, tile_order
from pipeline.maps.writer import LayerShape, create_map, write_map
from pipeline.store import artifact_attrs

GRID = GridSpec(rows=20, cols=22, cell_size_m=0.5, origin_xy=(0.0, 10.0))
LAT = Lattice(GRID, 0.0, 0.0, 2.0, 0.5)
TILE = 4  # chunks of 16 rows


def _map(seed=0):
    rng = np.random.default_rng(seed)
    cell = np.sort(rng.choice(GRID.rows * GRID.cols, 150, replace=False))
    cells = MapCells(cell=cell, features=rng.standard_normal((150, 8)).astype(np.float32),
                     weight=rng.random(150).astype(np.float32), count=rng.integers(0, 9, 150).astype(np.int32),
                     level=rng.integers(0, 4, 150).astype(np.int16))
    r, c = np.divmod(cell, GRID.cols)
    key = np.stack([np.repeat(r, 2), np.repeat(c, 2), np.tile([0, 2], 150)], axis=1).astype(np.int16)
    voxels = MapVoxels(key=key, features=rng.standard_normal((300, 8)).astype(np.float16),
                       weight=rng.random(300).astype(np.float32), count=np.ones(300, np.int32))
    return cells, voxels


def _attrs():
    return artifact_attrs("cfmap", FORMAT_VERSION, "cfmap", "blake2b:t", encoder={"name": "test", "dim": 8})


def _files(path: Path) -> dict[str, bytes]:
    return {str(f.relative_to(path)): f.read_bytes() for f in sorted(path.rglob("*")) if f.is_file()}


def test_blocks_of_any_size_give_the_bytes_of_one_piece(tmp_path):
    cells, voxels = _map()
    write_map(tmp_path / "whole.zarr", _attrs(), GRID, LAT, cells, tile_cells=TILE, voxels=voxels)
    order, _ = tile_order(cells.cell, GRID, TILE)
    for sizes in ((1,), (5, 16, 3), (150,)):
        (writer,) = create_map(tmp_path / f"blocks{sizes}.zarr", _attrs(), [LayerShape(GRID, LAT, 150, 8, 300)],
                               tile_cells=TILE)
        s = 0
        while s < 150:
            n = sizes[(s // 7) % len(sizes)]
            o = order[s : s + n]
            writer.add_cells(cells.cell[o], cells.features[o], cells.weight[o], cells.count[o], cells.level[o])
            s += n
        for v in range(0, 300, 37):
            writer.add_voxels(voxels.key[v : v + 37], voxels.features[v : v + 37], voxels.weight[v : v + 37],
                              voxels.count[v : v + 37])
        writer.close()
        assert _files(tmp_path / f"blocks{sizes}.zarr") == _files(tmp_path / "whole.zarr")
    m = SemanticMap(tmp_path / "whole.zarr")
    assert m.n_cells == 150 and len(m.voxels()) == 300


def test_what_a_layer_is_given_is_checked(tmp_path):
    cells, voxels = _map()
    order, _ = tile_order(cells.cell, GRID, TILE)
    (writer,) = create_map(tmp_path / "a.zarr", _attrs(), [LayerShape(GRID, LAT, 150, 8)], tile_cells=TILE)
    args = lambda o: (cells.cell[o], cells.features[o], cells.weight[o], cells.count[o], cells.level[o])  # noqa: E731
    writer.add_cells(*args(order[5:10]))
    with pytest.raises(ValueError, match="tile-major order, each once"):
        writer.add_cells(*args(order[:5]))  # behind the last one
    with pytest.raises(ValueError, match="tile-major order, each once"):
        writer.add_cells(*args(order[9:12]))  # one cell twice
    with pytest.raises(ValueError, match="created without voxels"):
        writer.add_voxels(voxels.key[:1], voxels.features[:1], voxels.weight[:1], voxels.count[:1])
    with pytest.raises(ValueError, match="5 rows written of the 150 announced"):
        writer.close()
    (writer,) = create_map(tmp_path / "b.zarr", _attrs(), [LayerShape(GRID, LAT, 3, 8)], tile_cells=TILE)
    with pytest.raises(ValueError, match="more than the 3 rows announced"):
        writer.add_cells(*args(order[:4]))
