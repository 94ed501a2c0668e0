"""An accumulator's storage: sums in segments (the same bytes as one tensor, growth that copies nothing) and the
voxel slot index paged by squares (the entries of one tensor, memory by the squares written)."""

import numpy as np
import pytest
import torch

from pipeline.encoders.base import PaletteFeatures
from pipeline.geometry import GridSpec
from pipeline.maps.fusion import BlockPoints, TopDownAccumulator, VoxelAccumulator
from pipeline.maps.segments import PAGE_CELLS, SegmentedRows, TilePagedIndex
from pipeline.maps.store import Lattice

LAT = Lattice(GridSpec(rows=30, cols=40, cell_size_m=0.5, origin_xy=(0.0, 15.0)), 0.0, 0.0, 2.0, 0.5)  # 4 levels


def test_operations_across_segments_give_the_bytes_of_one_tensor():
    rng = np.random.default_rng(3)
    rows = SegmentedRows(5, torch.device("cpu"), capacity=10, segment_rows=8)
    plain = torch.empty((0, 5))
    for capacity in (10, 23, 64):
        rows.reserve(capacity)
        rows.zero_range_(len(plain), capacity)  # rows are unwritten until set
        plain = torch.cat([plain, torch.zeros((capacity - len(plain), 5))])
        slots = torch.from_numpy(rng.integers(0, capacity, 200))  # repeats add in their order
        add = torch.from_numpy(rng.standard_normal((200, 5)).astype(np.float32)) * 1e3
        rows.index_add_(slots, add)
        plain.index_add_(0, slots, add)
        zeroed = torch.from_numpy(rng.integers(0, capacity, 7))
        rows.zero_(zeroed)
        plain[zeroed] = 0
        everything = torch.arange(capacity)
        assert torch.equal(rows.gather(everything), plain)
        picked = torch.from_numpy(rng.permutation(capacity)[:13])
        assert torch.equal(rows.gather(picked), plain[picked])
    assert rows.capacity == 64 and len(rows.segments) == 8
    assert rows.gather(torch.zeros(0, dtype=torch.int64)).shape == (0, 5)


def test_growth_adds_segments_and_moves_no_row():
    rows = SegmentedRows(3, torch.device("cpu"), capacity=4, segment_rows=4)
    rows.zero_range_(0, 4)
    rows.index_add_(torch.tensor([1, 2]), torch.ones((2, 3)))
    first = rows.segments[0].data_ptr()
    rows.reserve(17)
    assert rows.capacity == 20 and rows.segments[0].data_ptr() == first  # the held rows stayed where they were
    assert rows.gather(torch.tensor([1, 2])).tolist() == [[1.0] * 3] * 2


def test_a_segment_size_that_is_not_a_power_of_two_is_refused():
    with pytest.raises(ValueError, match="segment_rows must be a power of two, got 12"):
        SegmentedRows(3, torch.device("cpu"), segment_rows=12)


def _blocks(seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(4):
        n = 500
        points = BlockPoints(cell=rng.integers(-1, LAT.cells, n), level=rng.integers(0, LAT.levels, n),
                             dist_m=rng.random(n).astype(np.float32))
        if rng.random() < 0.5:
            features = torch.from_numpy(rng.standard_normal((n, 6)).astype(np.float32))
        else:
            palette = torch.from_numpy(rng.standard_normal((9, 6)).astype(np.float32))
            features = PaletteFeatures(palette, torch.from_numpy(rng.integers(0, 9, (1, n, 1))),
                                       torch.ones(1, n, 1, dtype=torch.bool), (n, 1))
        yield points, features, rng.random(n).astype(np.float32)


@pytest.mark.parametrize("acc_cls", [TopDownAccumulator, VoxelAccumulator])
def test_accumulators_in_small_segments_hold_the_same_bytes(acc_cls, monkeypatch):
    def build():
        chunks = []
        for seed in range(3):
            acc = acc_cls(LAT, 6)
            for block in _blocks(seed):
                acc.add(*block)
            chunks.append(acc.state())
        fold = acc_cls(LAT, 6)
        for state in chunks:
            fold.merge(state)
        return fold, fold.state()

    _, one = build()  # every accumulator in one segment
    monkeypatch.setattr("pipeline.maps.segments.SEGMENT_ROWS", 16)
    fold, many = build()
    assert len(fold.store.sum.segments) > 20 and len(one.keys) > 300
    assert np.array_equal(one.keys, many.keys)
    for name in ("sum", "weight", "count", "top"):
        a, b = getattr(one, name), getattr(many, name)
        assert (a is None and b is None) or torch.equal(a, b), name


def test_the_paged_index_reads_back_what_one_tensor_would():
    rows, cols, levels = 150, 70, 3  # squares of 64: 3 x 2 per level, the last row and column narrower
    index = TilePagedIndex(rows, cols, levels, torch.device("cpu"))
    plain = torch.full((rows * cols * levels,), -1, dtype=torch.int32)
    rng = np.random.default_rng(5)
    for _ in range(6):
        keys = torch.from_numpy(rng.choice(rows * cols * levels, 400, replace=False))
        values = torch.from_numpy(rng.integers(0, 1 << 30, 400))
        index[keys] = values
        plain[keys] = values.to(torch.int32)
        probe = torch.from_numpy(rng.integers(0, rows * cols * levels, 2000))  # written or not, repeats
        assert torch.equal(index[probe], plain[probe])
    assert index.pages == 3 * 3 * 2  # every square of every level written by now
    corner = torch.tensor([rows * cols - 1, rows * cols * levels - 1])  # the last cell, at levels 0 and 2
    assert index[corner].tolist() == plain[corner].tolist()


def test_the_paged_index_takes_memory_for_the_squares_written_not_the_lattice():
    rows, cols, levels = 1200, 2000, 21  # a 100 m x 60 m office at 5 cm: 200 MB as one int32 tensor
    index = TilePagedIndex(rows, cols, levels, torch.device("cpu"))
    row, col = np.meshgrid(np.arange(300, 400), np.arange(500, 560), indexing="ij")  # 5 m x 3 m seen
    keys = torch.from_numpy(np.concatenate([lvl * rows * cols + (row * cols + col).ravel() for lvl in (0, 4, 9)]))
    index[keys] = torch.arange(len(keys))
    assert torch.equal(index[keys], torch.arange(len(keys), dtype=torch.int32))
    assert index.pages == 3 * 3 * 2  # levels x square rows (256-319, 320-383, 384-447) x columns (448-511, 512-575)
    assert index.entries.numel() * 4 <= 2 * index.pages * PAGE_CELLS**2 * 4 < 2 * 2**20  # under 2 MB, not 200
    assert index[torch.tensor([0, rows * cols * levels - 1])].tolist() == [-1, -1]
