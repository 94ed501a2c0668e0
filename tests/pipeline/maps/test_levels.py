"""Level-aware cfmap scores (pipeline.maps.levels) and the fp16 feature products."""

import numpy as np
import pytest

from pipeline.encoders.oracle import OracleEncoder
from pipeline.errors import ArtifactError
from pipeline.geometry import GridSpec
from pipeline.maps.fusion import BlockPoints, VoxelAccumulator
from pipeline.maps.levels import LevelScorer
from pipeline.maps.scoring import chunked_scores
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
