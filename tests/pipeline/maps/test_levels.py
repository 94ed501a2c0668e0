"""Level-aware cfmap scores (pipeline.maps.levels) and the fp16 feature products."""

import numpy as np
import pytest

from pipeline.encoders.oracle import OracleEncoder
from pipeline.errors import ArtifactError
from pipeline.geometry import GridSpec
from pipeline.maps.fusion import BlockPoints, VoxelAccumulator
from pipeline.maps.levels import LevelScorer
from pipeline.maps.scoring import chunked_scores, logsumexp
from pipeline.maps.store import FORMAT_VERSION, Lattice, SemanticMap
from pipeline.maps.writer import write_map
from pipeline.store import artifact_attrs

GRID = GridSpec(rows=4, cols=4, cell_size_m=1.0, origin_xy=(0.0, 4.0))
LAT = Lattice(GRID, 0.0, 0.0, 3.0, 1.0)
ENC = OracleEncoder(dim=64)
T = 0.1


def _map(path, artifact="cfmap"):
    """Cell 5: a wall (background) on top of a picture (level 1 of 2); cell 6: a chair only; cell 9: wall."""
    pts = [(5, 2, "background"), (5, 1, "picture"), (6, 0, "chair"), (9, 2, "background"), (9, 0, "background")]
    block = BlockPoints(cell=np.array([p[0] for p in pts]), level=np.array([p[1] for p in pts]),
                        dist_m=np.ones(len(pts), np.float32))
    import torch

    feats = torch.from_numpy(np.stack([ENC.word_vector(p[2]) for p in pts]).astype(np.float32))
    vox = VoxelAccumulator(LAT, 64)
    vox.add(block, feats)
    v = vox.result()
    write_map(path, artifact_attrs(artifact, FORMAT_VERSION, artifact, "x", encoder=ENC.identity()), GRID, LAT,
              v.top_down().to_store(), tile_cells=2, voxels=v.to_store(GRID) if artifact == "cfmap" else None)
    return SemanticMap(path)


def _prob(s, lse):
    return 1.0 / (1.0 + np.exp(lse - s / T))


def test_best_level_finds_the_picture_under_the_wall(tmp_path):
    m = _map(tmp_path / "cfmap.zarr")
    assert m.has_voxels
    q = ENC.encode_text(["picture"]).numpy()[0]
    bg = ENC.encode_text(["other", "wall"]).numpy()
    top_s = m.dot(q)
    bg_s = m.dot(bg)
    top_max, top_lse = bg_s.max(1), np.log(np.exp(bg_s / T).sum(1))
    row = {int(c): i for i, c in enumerate(m.cell)}
    assert _prob(top_s, top_lse)[row[5]] < 0.01  # the top-down view shows only the wall
    s, bmax, blse = LevelScorer(m).cell_scores(q, bg, T, top_s, top_max, top_lse)
    p = _prob(s, blse)
    assert p[row[5]] > 0.99 and s[row[5]] > bmax[row[5]]  # ... the level below is the picture
    assert p[row[6]] < 0.5 and p[row[9]] < 0.01  # chair, wall: no level is a picture (no win)
    # a query whose best level is the top gets the top-down values back
    qc = ENC.encode_text(["chair"]).numpy()[0]
    s2, _, _ = LevelScorer(m).cell_scores(qc, bg, T, m.dot(qc), top_max, top_lse)
    np.testing.assert_allclose(s2[row[6]], m.dot(qc)[row[6]], atol=1e-3)


def test_without_background_the_highest_score_wins(tmp_path):
    m = _map(tmp_path / "cfmap.zarr")
    q = ENC.encode_text(["picture"]).numpy()[0]
    n = m.n_cells
    s, bmax, blse = LevelScorer(m).cell_scores(q, None, T, np.zeros(n), np.full(n, -np.inf), np.full(n, -np.inf))
    row = {int(c): i for i, c in enumerate(m.cell)}
    assert s[row[5]] == pytest.approx(1.0, abs=1e-3) and np.isneginf(bmax).all()


def test_vlmap_has_no_levels(tmp_path):
    m = _map(tmp_path / "vlmap.zarr", artifact="vlmap")
    assert not m.has_voxels
    with pytest.raises(ArtifactError, match="cfmap_voxels: true"):
        LevelScorer(m)


def test_fp16_products_match_fp32_and_features_stay_half(tmp_path):
    m = _map(tmp_path / "cfmap.zarr")
    assert m.features16().dtype == np.float16 and m.features().dtype == np.float32
    text = ENC.encode_text(["picture", "chair", "wall"]).numpy()
    np.testing.assert_allclose(m.dot(text), m.features() @ text.T, atol=1e-6)
    np.testing.assert_allclose(m.dot(text[0], rows=[1, 0]), m.features()[[1, 0]] @ text[0], atol=1e-6)
    rng = np.random.default_rng(0)
    f = rng.standard_normal((1000, 64)).astype(np.float32)
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    got = chunked_scores(f.astype(np.float16), text, chunk_rows=300)  # 4 chunks, the last one short
    np.testing.assert_allclose(got, f.astype(np.float16).astype(np.float32) @ text.T, atol=1e-6)
    assert got.dtype == np.float32 and got.shape == (1000, 3)


# ----------------------------------------------------------------------------- block by block (a map of many blocks)


@pytest.fixture(scope="module")
def tiled_cfmap(tmp_path_factory):
    from tests.fixtures.level_maps import write_tiled_cfmap

    return write_tiled_cfmap(tmp_path_factory.mktemp("levels") / "cfmap.zarr")


def _inputs(smap, text, background=("other", "floor", "wall")):
    """The query feature, the background prompts in play (the query's own left out) and the top-down values."""
    from tests.fixtures.level_maps import ENC as TENC

    q = TENC.encode_text([text]).numpy()[0]
    bg = TENC.encode_text(list(background)).numpy() if background else None
    if bg is not None:
        bg = bg[bg @ q <= 0.99]
    top_s = smap.dot(q)
    if bg is None or not len(bg):
        inf = np.full(smap.n_cells, -np.inf, np.float32)
        return q, bg, (top_s, inf, inf)
    bs = smap.dot(bg)
    return q, bg, (top_s, bs.max(axis=1), logsumexp(bs / np.float32(T), axis=1))


@pytest.mark.parametrize("chunk_rows", [4096, 1024, 100])
def test_streamed_scores_are_the_bytes_of_the_whole_array_computation(tiled_cfmap, chunk_rows):
    from tests.fixtures.level_maps import HIDDEN_CHAIR, whole_array_level_scores

    m = SemanticMap(tiled_cfmap)
    scorer = LevelScorer(m, chunk_rows=chunk_rows)
    assert scorer.n_blocks == -(-len(m.voxels()) // chunk_rows) and scorer.n_blocks >= 9
    for text, background in (("chair", ("other", "floor", "wall")), ("bed", ("other", "floor", "wall")),
                             ("floor", ("other", "floor", "wall")), ("table", ()), ("lamp", ("other",))):
        q, bg, top = _inputs(m, text, background)
        got = scorer.cell_scores(q, bg, T, *top)
        want = whole_array_level_scores(m, q, bg, T, *top, chunk_rows=chunk_rows)
        for a, b in zip(got, want):
            assert a.dtype == np.float32
            np.testing.assert_array_equal(a, b)
    # the chair under the table wins its cells through its level; the top-down view gives them to the table
    q, bg, top = _inputs(m, "chair")
    s, _, blse = scorer.cell_scores(q, bg, T, *top)
    hidden = m.index[HIDDEN_CHAIR].ravel()
    hidden = hidden[hidden >= 0]
    assert (_prob(s, blse)[hidden] > 0.5).mean() > 0.8 and (_prob(top[0], top[2])[hidden] < 0.5).all()


def test_bed_ties_straddle_block_edges(tiled_cfmap):
    """The bed's levels hold one feature per cell (equal logits): the fixture has cells whose tied voxels lie in two
    blocks, so the byte-for-byte test above covers the ties the blocks split."""
    m = SemanticMap(tiled_cfmap)
    key = m.voxels().key.astype(np.int64)
    flat = key[:, 0] * m.grid.cols + key[:, 1]
    bed = np.zeros(m.grid.rows * m.grid.cols, bool)
    bed[[r * m.grid.cols + c for r in range(90, 130) for c in range(20, 60)]] = True
    edge = np.arange(100, len(flat), 100)  # chunk_rows 100: a block starts at each
    assert (bed[flat[edge]] & (flat[edge] == flat[edge - 1])).sum() >= 3


def test_the_best_voxel_per_cell_is_the_whole_array_s_across_any_blocks():
    """Per cell the highest logit, the earliest voxel on ties, NaN last: whatever the blocks, as one lexsort."""
    from pipeline.maps.levels import _Best

    rng = np.random.default_rng(1)
    n_cells, n = 50, 2000
    cell = np.sort(rng.integers(0, n_cells, n))  # voxels in cell order, as stored
    logit = rng.integers(0, 4, n).astype(np.float32)  # many ties
    logit[rng.random(n) < 0.1] = np.nan
    logit[cell == 7] = np.nan  # a cell of NaN only: its first voxel
    value = np.arange(n, dtype=np.float32)  # tells which voxel was picked
    order = np.lexsort((np.arange(n), -logit, cell))
    first = np.r_[True, cell[order][1:] != cell[order][:-1]]
    want = np.full(n_cells, -1.0, np.float32)
    want[cell[order[first]]] = value[order[first]]
    for edges in ([n], [13, 700, 701, n], sorted(set(rng.integers(1, n, 40)) | {n})):
        best, s = _Best(n_cells), 0
        for e in edges:
            best.update(cell[s:e], logit[s:e], value[s:e], value[s:e], value[s:e])
            s = e
        got = np.where(best.has, best.s, -1.0)
        np.testing.assert_array_equal(got, want)


def test_a_region_reads_only_the_blocks_that_can_hold_it(tiled_cfmap, monkeypatch):
    from pipeline.region import Window
    from tests.fixtures.level_maps import whole_array_level_scores
    from tests.fixtures.tiled_maps import chunk_reads, chunks_of

    m = SemanticMap(tiled_cfmap)
    chunk = m.group["voxels"]["features"].chunks[0]
    key = m.voxels().key.astype(np.int64)
    flat = key[:, 0] * m.grid.cols + key[:, 1]
    q, bg, top = _inputs(m, "chair")
    floor = whole_array_level_scores(m, q, bg, T, *top, chunk_rows=chunk)
    # a box, a band of whole rows, one column (every block: each spans whole rows), the last cell, an unobserved box
    for win in (Window(20, 40, 25, 45), Window(60, 70, 0, 230), Window(0, 150, 100, 101), Window(149, 150, 229, 230),
                Window(0, 64, 150, 230)):
        scorer = LevelScorer(m, chunk_rows=chunk)
        idx = m.index_in(win)
        rows = np.sort(idx[idx >= 0])
        blocks = scorer.blocks_in(win)
        # every block whose (row, col) key range meets the window, by brute force over the window's cells
        r, c = np.mgrid[win.r0:win.r1, win.c0:win.c1]
        cells = np.sort((r * m.grid.cols + c).ravel())
        first, last = flat[::chunk], flat[np.minimum(np.arange(chunk, len(flat) + chunk, chunk), len(flat)) - 1]
        meets = np.searchsorted(cells, first) < np.searchsorted(cells, last, side="right")
        np.testing.assert_array_equal(blocks, np.flatnonzero(meets))
        with chunk_reads(monkeypatch) as reads:
            got = scorer.cell_scores(q, bg, T, *(a[rows] for a in top), window=win)
        # the keys of those blocks, and the features of the blocks holding a voxel of the window's observed cells
        keys = sorted(int(k.split("/")[3]) for k in reads.keys_read if k.startswith("voxels/key/"))
        feats = sorted(int(k.split("/")[3]) for k in reads.keys_read if k.startswith("voxels/features/"))
        holding = np.unique(np.flatnonzero(win.contains(key[:, 0], key[:, 1]) & (m.index[key[:, 0], key[:, 1]] >= 0))
                            // chunk)
        assert keys == list(blocks) and feats == list(holding)
        n_blocks = chunks_of(tiled_cfmap, "voxels/features")
        if win.shape[1] > 1:  # a box or a band: a few blocks (the column meets every block: each spans whole rows)
            assert len(keys) <= n_blocks // 3
        for a, b in zip(got, floor):
            np.testing.assert_array_equal(a, b[rows])
        if win == Window(0, 64, 150, 230):  # nothing observed there: no feature read, the outputs empty
            assert not feats and len(rows) == 0 and all(len(a) == 0 for a in got)


def test_a_window_s_scores_must_match_its_cells(tiled_cfmap):
    from pipeline.region import Window

    m = SemanticMap(tiled_cfmap)
    q, bg, top = _inputs(m, "chair")
    with pytest.raises(ValueError, match=r"399 top-down scores for the 400 observed cells of Window"):
        LevelScorer(m).cell_scores(q, bg, T, *(a[:399] for a in top), window=Window(20, 40, 25, 45))


def test_memory_is_a_block_not_the_voxels(tiled_cfmap):
    """Scoring holds one block and a few values per cell; the voxels' features (float16) are far larger."""
    import tracemalloc

    m = SemanticMap(tiled_cfmap)
    m.index  # noqa: B018 - the (rows, cols) index, read before measuring: a grid, not the voxels
    q, bg, top = _inputs(m, "chair")
    voxel_bytes = len(m.voxels()) * m.dim * 2
    scorer = LevelScorer(m, chunk_rows=1024)
    scorer.block_bounds()
    tracemalloc.start()
    scorer.cell_scores(q, bg, T, *top)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"peak {peak / 2**20:.2f} MB, voxel features {voxel_bytes / 2**20:.2f} MB, {m.n_cells} cells")
    assert peak < voxel_bytes / 2  # the whole-array computation: more than twice voxel_bytes


def test_features_are_held_from_the_second_call_when_they_fit(tiled_cfmap, monkeypatch):
    from tests.fixtures.tiled_maps import chunk_reads

    m = SemanticMap(tiled_cfmap)
    q, bg, top = _inputs(m, "bed")
    held, streamed = LevelScorer(m, chunk_rows=1024, hold_mb=64), LevelScorer(m, chunk_rows=1024, hold_mb=0.5)
    first = held.cell_scores(q, bg, T, *top)
    assert not held.held
    for _ in range(2):
        assert all((a == b).all() for a, b in zip(held.cell_scores(q, bg, T, *top), first))
        assert all((a == b).all() for a, b in zip(streamed.cell_scores(q, bg, T, *top), first))
    assert held.held and not streamed.held  # 0.5 MB: smaller than its features
    with chunk_reads(monkeypatch) as reads:
        held.cell_scores(q, bg, T, *top)
    assert not reads  # keys and features held, the background of this set cached
    other = held.cell_scores(q, bg[:1], T, *top)  # another background set: computed from the held features
    want = streamed.cell_scores(q, bg[:1], T, *top)
    assert all((a == b).all() for a, b in zip(other, want))
    assert len(held._bg) == 1  # one background set at a time


def test_a_store_whose_voxel_keys_do_not_ascend_is_refused_before_a_region_is_read(tiled_cfmap, tmp_path):
    """A region's blocks are found from each block's first and last key, which says nothing when the keys do not
    ascend (a store zipon did not write): the pass that finds them names the store and the row, and says how to
    rebuild, rather than miss voxels."""
    import shutil

    import zarr

    from pipeline.region import Window

    path = shutil.copytree(tiled_cfmap, tmp_path / "cfmap.zarr")
    key = zarr.open_array(str(path / "voxels" / "key"), mode="r+")
    rows = key[5000:5002]
    key[5000:5002] = rows[::-1]  # two voxels swapped
    scorer = LevelScorer(SemanticMap(path))
    with pytest.raises(ArtifactError, match=r"cfmap\.zarr: voxels/key row 5001 does not come after the row before "
                                            r"it .*rebuild it: zipon run --force --stage cfmap"):
        scorer.blocks_in(Window(0, 10, 0, 10))
