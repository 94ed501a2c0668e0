"""The fold cache: what is stored loads back bit for bit, and anything else (another key, chunk size, a
half-written or damaged folder) loads as no fold at all."""

import json

import numpy as np
import torch

from pipeline.maps.fusion import FusionState
from pipeline.maps.incremental import Fold, load_fold, save_fold


def _fold(top: bool = True) -> Fold:
    rng = np.random.default_rng(0)
    state = FusionState(keys=np.array([3, 8, 40]), sum=torch.from_numpy(rng.standard_normal((3, 5)).astype(np.float32)),
                        weight=torch.tensor([1.5, 2.0, 1e-15], dtype=torch.float64), count=torch.tensor([2, 3, 1]),
                        top=torch.tensor([0, 4, 2]) if top else None)
    return Fold("blake2b:key", 16, ["blake2b:c0", "blake2b:c1"], [state], frames_fused=30, pixels=1234)


def test_a_saved_fold_loads_back_bit_for_bit(tmp_path):
    (tmp_path / "f.tmp-999999").mkdir()  # left by a crashed run
    for top in (True, False):
        fold = _fold(top)
        save_fold(tmp_path / "f", fold)
        got = load_fold(tmp_path / "f", "blake2b:key", 16)
        assert got is not None and got.chunks == fold.chunks and got.frames == 32
        assert (got.frames_fused, got.pixels) == (30, 1234)
        assert np.array_equal(got.states[0].keys, fold.states[0].keys)
        for name in ("sum", "weight", "count"):
            assert torch.equal(getattr(got.states[0], name), getattr(fold.states[0], name))
        assert (got.states[0].top is None) == (not top) and (not top or torch.equal(got.states[0].top, fold.states[0].top))
    assert [p.name for p in tmp_path.iterdir()] == ["f"]  # replaced in place, no temporary left


def test_another_build_or_a_damaged_fold_is_no_fold(tmp_path):
    path = tmp_path / "f"
    assert load_fold(path, "blake2b:key", 16) is None  # none yet
    save_fold(path, _fold())
    assert load_fold(path, "blake2b:other", 16) is None  # other params / code / lattice / encoder
    assert load_fold(path, "blake2b:key", 32) is None  # other chunk size
    (path / "count.npy").write_bytes(b"not an array")
    assert load_fold(path, "blake2b:key", 16) is None
    save_fold(path, _fold())
    np.save(path / "sum.npy", np.zeros((2, 5), np.float32))  # rows that do not match the keys
    assert load_fold(path, "blake2b:key", 16) is None
    save_fold(path, _fold())
    (path / "meta.json").write_text(json.dumps({"format": 1}))
    assert load_fold(path, "blake2b:key", 16) is None


def test_a_buildings_fold_keeps_one_state_per_floor(tmp_path):
    one = _fold()
    upper = FusionState(keys=np.array([5]), sum=torch.ones((1, 5)), weight=torch.tensor([2.0], dtype=torch.float64),
                        count=torch.tensor([4]), top=torch.tensor([1]))
    building = Fold(one.key, 16, one.chunks, [one.states[0], upper], frames_fused=30, pixels=1234)
    save_fold(tmp_path / "f", building)
    assert sorted(p.name for p in (tmp_path / "f").glob("floor1.*")) == [
        "floor1.count.npy", "floor1.keys.npy", "floor1.sum.npy", "floor1.top.npy", "floor1.weight.npy"]
    got = load_fold(tmp_path / "f", "blake2b:key", 16)
    assert got is not None and len(got.states) == 2
    assert np.array_equal(got.states[1].keys, [5]) and torch.equal(got.states[1].sum, upper.sum)
    assert torch.equal(got.states[0].sum, one.states[0].sum)
    (tmp_path / "f" / "floor1.keys.npy").unlink()  # a floor's arrays missing: no fold
    assert load_fold(tmp_path / "f", "blake2b:key", 16) is None
