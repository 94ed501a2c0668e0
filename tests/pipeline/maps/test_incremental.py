"""The fold cache: what is stored (split by tile) loads back bit for bit, and anything else (another key, chunk size,
tiles, a half-written or damaged folder) loads as no fold at all."""

import json

import numpy as np
import pytest
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fusion import FusionState
from pipeline.maps.incremental import FoldWriter, load_fold
from pipeline.maps.spill import TileLayout, write_state

LAYOUT = TileLayout(GridSpec(rows=10, cols=12, cell_size_m=0.5, origin_xy=(0.0, 5.0)), 4)  # 3 x 3 tiles


def _state(keys, top=True, seed=0) -> FusionState:
    rng = np.random.default_rng(seed)
    n = len(keys)
    return FusionState(keys=np.asarray(keys, np.int64), sum=torch.from_numpy(rng.standard_normal((n, 5)).astype(np.float32)),
                       weight=torch.from_numpy(rng.random(n) * 1e-15), count=torch.from_numpy(rng.integers(1, 9, n)),
                       top=torch.from_numpy(rng.integers(0, 4, n)) if top else None)


def _save(path, states, top=True, key="blake2b:key", chunk_frames=16) -> None:
    writer = FoldWriter(path, [LAYOUT] * len(states), 5, top=top)
    for floor, state in zip(writer.floors, states):
        write_state(floor, state)
    writer.commit(key, chunk_frames, ["blake2b:c0", "blake2b:c1"], 30, 1234)


def _tile_major(state: FusionState) -> np.ndarray:
    return np.lexsort((state.keys, LAYOUT.tile_of(state.keys)))


def test_a_saved_fold_loads_back_bit_for_bit_one_tile_at_a_time(tmp_path):
    (tmp_path / "f.tmp-999999").mkdir()  # left by a crashed run
    for top in (True, False):
        state = _state([3, 8, 40, 41, 119, 77], top)  # cells in tiles 0, 2, 1, 1, 8, 4
        _save(tmp_path / "f", [state], top)
        got = load_fold(tmp_path / "f", "blake2b:key", 16, [LAYOUT])
        assert got is not None and got.chunks == ["blake2b:c0", "blake2b:c1"] and got.frames == 32
        assert (got.frames_fused, got.pixels) == (30, 1234)
        rows = got.states[0]
        assert rows.nonempty().tolist() == [True, True, True, False, True, False, False, False, True]
        o = _tile_major(state)
        assert np.concatenate([rows.state(t).keys for t in range(9)]).tolist() == state.keys[o].tolist()
        for name in ("sum", "weight", "count") + (("top",) if top else ()):
            assert torch.equal(torch.cat([getattr(rows.state(t), name) for t in range(9)]), getattr(state, name)[o])
        assert (rows.state(3).top is None) == (not top)
    assert [p.name for p in tmp_path.iterdir()] == ["f"]  # replaced in place, no temporary left


def test_another_build_or_a_damaged_fold_is_no_fold(tmp_path):
    path = tmp_path / "f"
    assert load_fold(path, "blake2b:key", 16, [LAYOUT]) is None  # none yet
    _save(path, [_state([3, 8])])
    assert load_fold(path, "blake2b:other", 16, [LAYOUT]) is None  # other params / code / lattice / encoder
    assert load_fold(path, "blake2b:key", 32, [LAYOUT]) is None  # other chunk size
    assert load_fold(path, "blake2b:key", 16, [TileLayout(LAYOUT.grid, 5)]) is None  # other tiles
    assert load_fold(path, "blake2b:key", 16, [LAYOUT, LAYOUT]) is None  # another number of floors
    (path / "floor0.count.bin").write_bytes(b"short")
    assert load_fold(path, "blake2b:key", 16, [LAYOUT]) is None
    _save(path, [_state([3, 8])])
    (path / "floor0.json").unlink()  # a floor never finished
    assert load_fold(path, "blake2b:key", 16, [LAYOUT]) is None
    _save(path, [_state([3, 8])])
    (path / "meta.json").write_text(json.dumps({"format": 1}))  # the untiled format of before
    assert load_fold(path, "blake2b:key", 16, [LAYOUT]) is None


def test_an_aborted_fold_leaves_the_stored_one(tmp_path):
    path = tmp_path / "f"
    _save(path, [_state([3, 8])])
    writer = FoldWriter(path, [LAYOUT], 5, top=True)
    write_state(writer.floors[0], _state([1, 2], seed=1))
    writer.abort()
    got = load_fold(path, "blake2b:key", 16, [LAYOUT])
    assert got is not None and got.states[0].state(0).keys.tolist() == [3] and got.states[0].rows == 2
    assert [p.name for p in tmp_path.iterdir()] == ["f"]


def test_tiles_must_come_in_order(tmp_path):
    writer = FoldWriter(tmp_path / "f", [LAYOUT], 5, top=True)
    write_state(writer.floors[0], _state([40]))  # tile 1
    with pytest.raises(ValueError, match="tile order"):
        write_state(writer.floors[0], _state([3]))  # tile 0
    writer.abort()


def test_a_buildings_fold_keeps_one_state_per_floor(tmp_path):
    lower, upper = _state([3, 8]), _state([5], seed=2)
    _save(tmp_path / "f", [lower, upper])
    assert sorted(p.name for p in (tmp_path / "f").glob("floor1.*")) == [
        "floor1.count.bin", "floor1.json", "floor1.keys.bin", "floor1.sum.bin", "floor1.tiles.npy", "floor1.top.bin",
        "floor1.weight.bin"]
    got = load_fold(tmp_path / "f", "blake2b:key", 16, [LAYOUT, LAYOUT])
    assert got is not None and len(got.states) == 2
    assert got.states[1].state(1).keys.tolist() == [5] and torch.equal(got.states[1].state(1).sum, upper.sum)
    assert torch.equal(got.states[0].state(0).sum, lower.sum[:1])
    (tmp_path / "f" / "floor1.keys.bin").unlink()  # a floor's arrays missing: no fold
    assert load_fold(tmp_path / "f", "blake2b:key", 16, [LAYOUT, LAYOUT]) is None
