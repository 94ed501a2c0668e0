"""Rows on disk by tile: the tile layout's key numbering, an accumulator spilled tile by tile, and the checks that
keep rows in tile order and unfinished or damaged sets unread."""

import numpy as np
import pytest
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fusion import BlockPoints, TopDownAccumulator, VoxelAccumulator
from pipeline.maps.spill import TileLayout, TileRows, TileRowsWriter, spill
from pipeline.maps.store import Lattice

GRID = GridSpec(rows=11, cols=13, cell_size_m=0.5, origin_xy=(0.0, 5.5))
LAT = Lattice(GRID, 0.0, 0.0, 1.5, 0.5)  # 3 levels
LAYOUT = TileLayout(GRID, 4)  # 3 x 4 tiles, the last row and column narrower


def test_local_keys_of_a_run_of_tiles_round_trip_and_keep_the_key_order():
    rng = np.random.default_rng(0)
    keys = np.sort(rng.choice(GRID.rows * GRID.cols * LAT.levels, 200, replace=False))
    tiles = LAYOUT.tile_of(keys)
    assert tiles.min() >= 0 and tiles.max() == LAYOUT.n_tiles - 1 == 11
    for first, stop in ((0, 1), (2, 7), (0, 12)):
        mine = keys[(tiles >= first) & (tiles < stop)]
        local = LAYOUT.local(mine, first, stop)
        squares = LAYOUT.fold_lattice(LAT, stop - first)
        assert local.min() >= 0 and local.max() < squares.cells * squares.levels
        assert np.array_equal(LAYOUT.global_keys(local, first, stop), mine)
        if stop - first == 1:  # within one tile, local order is key order
            assert np.array_equal(np.argsort(local, kind="stable"), np.arange(len(mine)))


@pytest.mark.parametrize("kind", [TopDownAccumulator, VoxelAccumulator])
def test_a_spilled_accumulator_is_its_state_split_by_tile(tmp_path, kind, monkeypatch):
    monkeypatch.setattr("pipeline.maps.spill.SPILL_ROWS", 7)  # gathered in many small blocks
    rng = np.random.default_rng(1)
    acc = kind(LAT, 6)
    pts = BlockPoints(cell=rng.integers(0, GRID.rows * GRID.cols, 300), level=rng.integers(0, 3, 300),
                      dist_m=np.ones(300, np.float32))
    acc.add(pts, torch.from_numpy(rng.standard_normal((300, 6)).astype(np.float32)))
    rows = spill(acc, LAYOUT, tmp_path, "chunk0")
    state = acc.state()
    tiles = LAYOUT.tile_of(state.keys)
    assert rows.rows == len(state.keys) and rows.nbytes > 0
    assert rows.nonempty().tolist() == [bool((tiles == t).any()) for t in range(LAYOUT.n_tiles)]
    for t in range(LAYOUT.n_tiles):
        mine = tiles == t
        part = rows.state(t)
        assert np.array_equal(part.keys, state.keys[mine])  # ascending within the tile
        for name in ("sum", "weight", "count") + (("top",) if kind is TopDownAccumulator else ()):
            assert torch.equal(getattr(part, name), getattr(state, name)[torch.from_numpy(mine)])
    both = rows.state(3, 9)
    assert np.array_equal(both.keys, np.concatenate([state.keys[tiles == t] for t in range(3, 9)]))


def test_rows_out_of_tile_order_or_of_the_wrong_shape_are_refused(tmp_path):
    writer = TileRowsWriter(tmp_path, "x", LAYOUT, {"a": ("<f4", (2,))})
    writer.append(np.array([1, 1, 3]), a=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="tile order"):
        writer.append(np.array([2]), a=np.zeros((1, 2)))
    with pytest.raises(ValueError, match="tile order"):
        writer.append(np.array([5, 4]), a=np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"column a of shape \(1, 3\), expected \(1, 2\)"):
        writer.append(np.array([5]), a=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="columns"):
        writer.append(np.array([5]), b=np.zeros((1, 2)))
    rows = writer.close()
    assert rows.rows == 3 and rows.tiles.tolist()[:5] == [0, 0, 2, 2, 3]


def test_an_unfinished_or_damaged_set_is_not_read(tmp_path):
    writer = TileRowsWriter(tmp_path, "x", LAYOUT, {"a": ("<i8", ())})
    writer.append(np.array([0, 2]), a=np.array([7, 8]))
    with pytest.raises(FileNotFoundError):
        TileRows(tmp_path, "x")  # no x.json until close()
    writer.close()
    assert TileRows(tmp_path, "x").span(2)["a"].tolist() == [8]
    rows = TileRows(tmp_path, "x")
    (tmp_path / "x.a.bin").write_bytes(b"\0" * 8)  # shrunk after it was opened: a read says so, naming the file
    with pytest.raises(ValueError, match=r"x\.a\.bin: rows \[0, 2\) of 2 asked, the file holds 1 rows"):
        rows.read("a")
    (tmp_path / "x.a.bin").write_bytes(b"\0" * 9)
    with pytest.raises(ValueError, match="9 bytes"):
        TileRows(tmp_path, "x")


def _mapped(folder) -> list[str]:
    """Files of ``folder`` this process has mapped (``/proc/self/maps``)."""
    return [line.split()[-1] for line in open("/proc/self/maps") if str(folder) in line]


def test_reads_copy_their_rows_and_leave_no_file_mapped(tmp_path):
    # pages read through a map that stays open count in the process's resident memory: a fold of a large floor
    # grew by everything it had read, so every read copies and closes its file
    writer = TileRowsWriter(tmp_path, "x", LAYOUT, {"a": ("<f4", (2,)), "b": ("<i8", ())})
    writer.append(np.array([0, 2, 2, 5]), a=np.arange(8).reshape(4, 2), b=np.array([10, 11, 12, 13]))
    rows = writer.close()
    span = rows.span(2, 6)
    assert span["a"].tolist() == [[2, 3], [4, 5], [6, 7]] and span["b"].tolist() == [11, 12, 13]
    assert rows.read("b").tolist() == [10, 11, 12, 13] and rows.read("a", 3).tolist() == [[6, 7]]
    assert rows.take("b", np.array([3, 0, 3])).tolist() == [13, 10, 13]
    assert rows.take("a", np.array([], np.int64)).shape == (0, 2)
    assert rows.nbytes == 4 * 2 * 4 + 4 * 8
    assert _mapped(tmp_path) == []
