"""Fusion against hand-computed cases: back-projection, the height rule, weights, voxels."""

import numpy as np
import pytest
import torch

from pipeline.encoders.base import PaletteFeatures
from pipeline.geometry import GridSpec, Intrinsics
from pipeline.maps.fusion import (BlockPoints, Lattice, TopDownAccumulator, VoxelAccumulator, depth_edges,
                                  locate_block, point_weights)

GRID = GridSpec(rows=4, cols=4, cell_size_m=1.0, origin_xy=(-2.0, 2.0))
LAT = Lattice(GRID, floor_z=0.0, min_height_m=0.0, max_height_m=3.0, level_height_m=1.0)


def looking_down(height: float) -> np.ndarray:
    """Camera at (0, 0, height) looking straight down: image right = +x, image down = -y."""
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = (1, 0, 0), (0, -1, 0), (0, 0, -1)
    T[:3, 3] = (0, 0, height)
    return T


def unit(v):
    v = np.asarray(v, np.float32)
    return v / np.linalg.norm(v)


def test_locate_block_hand_computed():
    # 2x2 image, f = 1, c = 0.5: pixel (u, v) -> camera ((u - 0.5) z, (v - 0.5) z, z).
    intr = Intrinsics(1.0, 1.0, 0.5, 0.5, 2, 2)
    depth = np.array([[[1.0, 1.0], [1.0, 2.0]]], np.float32)
    pts = locate_block(LAT, depth, np.ones((1, 2, 2), bool), looking_down(3.0)[None], intr,
                       depth_min_m=0.1, depth_max_m=10.0)
    # world points: (-0.5, 0.5, 2), (0.5, 0.5, 2), (-0.5, -0.5, 2), (1, -1, 1)
    # cells (row, col): (1,1), (1,2), (2,1), (3,3) -> flat r*4+c; levels 2, 2, 2, 1
    assert pts.cell.tolist() == [5, 6, 9, 15]
    assert pts.level.tolist() == [2, 2, 2, 1]
    np.testing.assert_allclose(pts.dist_m, [np.sqrt(1.5), np.sqrt(1.5), np.sqrt(1.5), np.sqrt(6.0)], rtol=1e-6)


def test_locate_block_drops_out_of_range_invalid_and_out_of_band():
    intr = Intrinsics(1.0, 1.0, 0.5, 0.5, 2, 2)
    depth = np.array([[[0.0, 1.0], [3.5, 1.0]]], np.float32)  # invalid; ok; below floor (z=-0.5); ok
    valid = np.array([[[True, True], [True, False]]])  # last pixel's feature invalid
    pts = locate_block(LAT, depth, valid, looking_down(3.0)[None], intr, depth_min_m=0.1, depth_max_m=10.0)
    assert pts.cell.tolist() == [-1, 6, -1, -1]
    pts = locate_block(LAT, depth, np.ones((1, 2, 2), bool), looking_down(3.0)[None], intr,
                       depth_min_m=0.1, depth_max_m=0.9)
    assert pts.n_fused == 0


def test_locate_block_keeps_only_the_floors_height_band():
    # the hand-computed block above: world z 2, 2, 2 and 1; a band [1.5, 3) keeps the first three, [0, 1.5) the last
    intr = Intrinsics(1.0, 1.0, 0.5, 0.5, 2, 2)
    depth = np.array([[[1.0, 1.0], [1.0, 2.0]]], np.float32)
    args = (LAT, depth, np.ones((1, 2, 2), bool), looking_down(3.0)[None], intr)
    upper = locate_block(*args, depth_min_m=0.1, depth_max_m=10.0, z_band=(1.5, 3.0))
    lower = locate_block(*args, depth_min_m=0.1, depth_max_m=10.0, z_band=(0.0, 1.5))
    assert upper.cell.tolist() == [5, 6, 9, -1] and lower.cell.tolist() == [-1, -1, -1, 15]
    every = locate_block(*args, depth_min_m=0.1, depth_max_m=10.0, z_band=(-np.inf, np.inf))
    assert every.cell.tolist() == [5, 6, 9, 15]


def test_depth_edges_flags_both_sides_of_a_jump():
    d = np.ones((1, 3, 4), np.float32)
    d[:, :, 2:] = 2.0
    e = depth_edges(d, 0.1)
    assert e[0].tolist() == [[False, True, True, False]] * 3
    assert not depth_edges(d, 0.0).any()


def _block(cells, levels, dists=None):
    cells = np.asarray(cells, np.int64)
    return BlockPoints(cell=cells, level=np.asarray(levels, np.int64),
                       dist_m=np.zeros(len(cells), np.float32) if dists is None else np.asarray(dists, np.float32))


FEATS = {k: unit(v) for k, v in dict(a=[1, 0, 0], b=[0, 1, 0], c=[0, 0, 1], d=[1, 1, 0], e=[1, 0, 1],
                                      f=[0, 1, 1], x=[1, 1, 1]).items()}


def _feats(names):
    return torch.from_numpy(np.stack([FEATS[n] for n in names]))


def _feed(acc, order=(0, 1)):
    # block 1: cell 5 gets a, b at level 1; cell 6 gets e at level 0; one pixel is not fused (cell -1)
    # block 2: cell 5 gets c at level 0 (below its top: dropped) and d at level 2 (a higher top: restart);
    #          cell 6 gets f at level 0 with weight 3
    blocks = [
        (_block([5, 5, 6, -1], [1, 1, 0, 0]), _feats("abex"), np.array([1, 1, 1, 1], np.float32)),
        (_block([5, 5, 6], [0, 2, 0]), _feats("cdf"), np.array([1, 1, 3], np.float32)),
    ]
    for i in order:
        acc.add(*blocks[i])


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_top_down_rule_hand_computed_and_order_independent(order):
    acc = TopDownAccumulator(LAT, 3)
    _feed(acc, order)
    out = acc.result()
    assert out.cell.tolist() == [5, 6]
    assert out.level.tolist() == [2, 0]
    np.testing.assert_allclose(out.features[0].numpy(), FEATS["d"], atol=1e-6)  # only the top level survives
    np.testing.assert_allclose(out.features[1].numpy(), unit(FEATS["e"] + 3 * FEATS["f"]), atol=1e-6)
    assert out.count.tolist() == [1, 2]
    np.testing.assert_allclose(out.weight, [1.0, 4.0])
    # points added while on top (block order matters here; the result above does not)
    assert acc.points_fused == (5 if order == (0, 1) else 3)


def test_voxels_keep_every_level_and_project_like_the_top_down_rule():
    vox = VoxelAccumulator(LAT, 3)
    _feed(vox)
    v = vox.result()
    got = {(int(c), int(l)): (v.sum[i].numpy(), float(v.weight[i]), int(v.count[i]))
           for i, (c, l) in enumerate(zip(v.cell, v.level))}
    assert sorted(got) == [(5, 0), (5, 1), (5, 2), (6, 0)]
    np.testing.assert_allclose(got[(5, 1)][0], FEATS["a"] + FEATS["b"], atol=1e-6)
    np.testing.assert_allclose(got[(6, 0)][0], FEATS["e"] + 3 * FEATS["f"], atol=1e-6)
    assert got[(6, 0)][1:] == (4.0, 2)
    top = TopDownAccumulator(LAT, 3)
    _feed(top)
    a, b = v.top_down(), top.result()
    assert a.cell.tolist() == b.cell.tolist() and a.level.tolist() == b.level.tolist()
    torch.testing.assert_close(a.features, b.features)


def test_point_weights_are_conceptfusion_confidence():
    w = point_weights(np.array([0.0, 0.6, 1.2], np.float32), 0.6)
    np.testing.assert_allclose(w, [1.0, np.exp(-0.5), np.exp(-2.0)], rtol=1e-6)
    assert point_weights(np.zeros(3, np.float32), None) is None


def test_storage_grows_past_its_first_capacity():
    grid = GridSpec(rows=100, cols=100, cell_size_m=0.1, origin_xy=(0.0, 10.0))
    lat = Lattice(grid, 0.0, 0.0, 1.0, 0.5)
    acc = TopDownAccumulator(lat, 2)
    cells = np.arange(10_000)
    acc.add(_block(cells, np.zeros(10_000)), torch.ones(10_000, 2))
    out = acc.result()
    assert len(out.cell) == 10_000 and out.count.tolist() == [1] * 10_000


@pytest.mark.parametrize("acc_cls", [TopDownAccumulator, VoxelAccumulator])
def test_far_points_keep_unit_features(acc_cls):
    # ConceptFusion weights at 5 m are ~1e-15: the weighted mean must still be a unit vector
    # (normalising the raw sums would clamp their ~1e-15 norm at 1e-12 and shrink the feature).
    acc = acc_cls(LAT, 3)
    dist = np.array([5.0, 5.0, 4.8], np.float32)
    acc.add(_block([5, 5, 6], [1, 1, 1], dist), _feats("aba"), point_weights(dist, 0.6))
    out = acc.result() if acc_cls is TopDownAccumulator else acc.result().top_down()
    np.testing.assert_allclose(out.features.norm(dim=1).numpy(), [1.0, 1.0], rtol=1e-5)
    np.testing.assert_allclose(out.features[0].numpy(), unit(FEATS["a"] + FEATS["b"]), atol=1e-6)
    np.testing.assert_allclose(out.features[1].numpy(), FEATS["a"], atol=1e-6)


def test_sparse_product_matches_index_add_with_weights():
    # the accumulator's one-hot sparse product against a direct index_add_ reference
    rng = np.random.default_rng(3)
    grid = GridSpec(rows=20, cols=20, cell_size_m=1.0, origin_xy=(0.0, 20.0))
    lat = Lattice(grid, 0.0, 0.0, 4.0, 1.0)
    cell = rng.integers(-1, 400, 5000)
    level = rng.integers(0, 4, 5000)
    feats = torch.from_numpy(rng.standard_normal((5000, 6)).astype(np.float32))
    w = rng.random(5000).astype(np.float32)
    vox = VoxelAccumulator(lat, 6)
    vox.add(_block(cell[:2500], level[:2500]), feats[:2500], w[:2500])
    vox.add(_block(cell[2500:], level[2500:]), feats[2500:], w[2500:])
    v = vox.result()
    key = np.where(cell >= 0, level * 400 + cell, -1)
    keys = np.unique(key[key >= 0])
    ref = torch.zeros(len(keys), 6, dtype=torch.float64).index_add_(
        0, torch.from_numpy(np.searchsorted(keys, key[key >= 0])), (feats[key >= 0] * torch.from_numpy(w[key >= 0])[:, None]).double())
    assert (v.level * 400 + v.cell).tolist() == keys.tolist()
    np.testing.assert_allclose(v.sum.numpy(), ref.numpy(), atol=1e-4)
    np.testing.assert_allclose(v.count.numpy(), np.bincount(np.searchsorted(keys, key[key >= 0])), atol=0)



@pytest.mark.parametrize("acc_cls", [TopDownAccumulator, VoxelAccumulator])
def test_palette_features_fuse_like_their_dense_rows(acc_cls):
    # an encoder whose cells take rows of a small table (the oracle) is fused in factored form:
    # same cells, levels, weights and counts as the dense rows; sums equal up to float32 rounding
    rng = np.random.default_rng(5)
    grid = GridSpec(rows=20, cols=20, cell_size_m=1.0, origin_xy=(0.0, 20.0))
    lat = Lattice(grid, 0.0, 0.0, 4.0, 1.0)
    palette = torch.nn.functional.normalize(torch.from_numpy(rng.standard_normal((7, 6)).astype(np.float32)), dim=1)
    fact, dense = acc_cls(lat, 6), acc_cls(lat, 6)
    for _ in range(3):  # blocks of 2 frames of 10x10 cells; later blocks restart some top-down cells
        index = torch.from_numpy(rng.integers(0, 7, (2, 10, 10)))
        pts = _block(rng.integers(-1, 400, 200), rng.integers(0, 4, 200))
        w = rng.random(200).astype(np.float32)
        fact.add(pts, PaletteFeatures(palette, index, torch.ones(2, 10, 10, dtype=torch.bool), (20, 20)), w)
        dense.add(pts, palette[index], w)
    a, b = fact.result(), dense.result()
    if acc_cls is VoxelAccumulator:
        assert a.cell.tolist() == b.cell.tolist() and a.level.tolist() == b.level.tolist()
        assert torch.equal(a.weight, b.weight) and torch.equal(a.count, b.count)
        torch.testing.assert_close(a.sum, b.sum, atol=1e-5, rtol=1e-5)
        a, b = a.top_down(), b.top_down()
    assert a.cell.tolist() == b.cell.tolist() and a.level.tolist() == b.level.tolist()
    np.testing.assert_array_equal(a.weight, b.weight)
    np.testing.assert_array_equal(a.count, b.count)
    torch.testing.assert_close(a.features, b.features, atol=1e-6, rtol=1e-6)
    assert fact.points_fused == dense.points_fused > 0


def test_palette_batches_concatenate_by_sharing_or_stacking_their_tables():
    ones = torch.ones(1, 2, 2, dtype=torch.bool)
    p, q = torch.eye(3), torch.eye(3).flip(0)
    idx = torch.tensor([[[0, 1], [2, 0]]])
    shared = PaletteFeatures.concat([PaletteFeatures(p, idx, ones, (4, 4)), PaletteFeatures(p, idx, ones, (4, 4))])
    assert shared.palette is p and shared.index.shape == (2, 2, 2)
    stacked = PaletteFeatures.concat([PaletteFeatures(p, idx, ones, (4, 4)), PaletteFeatures(q, idx, ones, (4, 4))])
    assert stacked.palette.shape == (6, 3)
    assert torch.equal(stacked.features, torch.cat([p[idx], q[idx]]))


# ----------------------------------------------------------------------------- chunk states and folds

def _random_blocks(n_blocks: int, seed: int = 7):
    rng = np.random.default_rng(seed)
    return [(_block(rng.integers(-1, 400, 300), rng.integers(0, 4, 300)),
             torch.from_numpy(rng.standard_normal((300, 6)).astype(np.float32)), rng.random(300).astype(np.float32))
            for _ in range(n_blocks)]


def _fold(acc_cls, lat, states):
    acc = acc_cls(lat, 6)
    for s in states:
        acc.merge(s)
    return acc.state()


@pytest.mark.parametrize("acc_cls", [TopDownAccumulator, VoxelAccumulator])
def test_chunk_states_fold_by_the_rules_of_one_stream(acc_cls):
    # the hand-computed case of _feed split into two chunks, one block each, folded in either order
    parts = []
    for i in (0, 1):
        acc = acc_cls(LAT, 3)
        _feed(acc, order=(i,))
        parts.append(acc.state())
    one = acc_cls(LAT, 3)
    _feed(one)
    for order in ((0, 1), (1, 0)):
        acc = acc_cls(LAT, 3)
        for i in order:
            acc.merge(parts[i])
        a, b = acc.result(), one.result()
        if acc_cls is VoxelAccumulator:
            assert a.cell.tolist() == b.cell.tolist() and a.level.tolist() == b.level.tolist()
            assert torch.equal(a.count, b.count) and torch.equal(a.weight, b.weight)
            a, b = a.top_down(), b.top_down()
        assert a.cell.tolist() == [5, 6] and a.level.tolist() == [2, 0] and a.count.tolist() == [1, 2]
        np.testing.assert_allclose(a.weight, [1.0, 4.0])
        torch.testing.assert_close(a.features, b.features)
    assert acc.state().points == (3 if acc_cls is TopDownAccumulator else 6)  # d, e, f; or all six


@pytest.mark.parametrize("acc_cls", [TopDownAccumulator, VoxelAccumulator])
def test_a_stored_fold_continued_gives_the_same_floats_as_folding_from_scratch(acc_cls):
    grid = GridSpec(rows=20, cols=20, cell_size_m=1.0, origin_xy=(0.0, 20.0))
    lat = Lattice(grid, 0.0, 0.0, 4.0, 1.0)
    chunks = []
    for c in range(4):  # 4 chunks of 3 random blocks: float sums whose value depends on the order of additions
        acc = acc_cls(lat, 6)
        for block in _random_blocks(3, seed=c):
            acc.add(*block)
        chunks.append(acc.state())
    scratch = _fold(acc_cls, lat, chunks)
    stored = _fold(acc_cls, lat, chunks[:2])
    resumed = _fold(acc_cls, lat, [stored] + chunks[2:])
    assert np.array_equal(resumed.keys, scratch.keys) and len(scratch.keys) > 100
    for name in ("sum", "weight", "count", "top"):
        a, b = getattr(resumed, name), getattr(scratch, name)
        assert (a is None and b is None) or torch.equal(a, b), name
    # and the fold is the stream's result up to float32 rounding
    one = acc_cls(lat, 6)
    for c in range(4):
        for block in _random_blocks(3, seed=c):
            one.add(*block)
    ref = one.state()
    assert np.array_equal(ref.keys, scratch.keys) and torch.equal(ref.count, scratch.count)
    torch.testing.assert_close(ref.sum, scratch.sum, atol=1e-4, rtol=1e-5)


def test_merge_refuses_a_state_of_the_other_kind():
    top, vox = TopDownAccumulator(LAT, 3), VoxelAccumulator(LAT, 3)
    _feed(top)
    with pytest.raises(ValueError, match="cannot fold"):
        vox.merge(top.state())
