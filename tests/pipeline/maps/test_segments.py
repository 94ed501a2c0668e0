"""The segmented sums of an accumulator: the same bytes as one tensor, and growth that copies nothing."""

import numpy as np
import pytest
import torch

from pipeline.encoders.base import PaletteFeatures
from pipeline.geometry import GridSpec
from pipeline.maps.fusion import BlockPoints, TopDownAccumulator, VoxelAccumulator
from pipeline.maps.segments import SegmentedRows
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
