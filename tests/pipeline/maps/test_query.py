"""Queries: heatmap formula, background rule, candidates (distance, angle, order), errors, pictures."""

import json
import math

import cv2
import numpy as np
import pytest

from pipeline.config import QueryParams
from pipeline.encoders.oracle import OracleEncoder
from pipeline.errors import ArtifactError, InputDataError, LineageError
from pipeline.geometry import GridSpec
from pipeline.maps.query import MapQuery, parse_pose
from pipeline.maps.render import render_map_pca, render_query
from pipeline.maps.store import FORMAT_VERSION, Lattice, MapCells, MapVoxels, SemanticMap
from pipeline.maps.writer import write_map
from pipeline.store import artifact_attrs

GRID = GridSpec(rows=40, cols=40, cell_size_m=0.1, origin_xy=(0.0, 4.0))
ENC = OracleEncoder(dim=64)


@pytest.fixture(scope="module")
def map_path(tmp_path_factory):
    """All cells observed: background, two chairs (5x5 and 4x4 cells), a table and a 1-cell chair."""
    label = np.zeros((40, 40), "<U10")
    label[:] = "background"
    label[5:10, 5:10] = "chair"
    label[30:34, 30:34] = "chair"
    label[20:25, 5:15] = "table"
    label[35, 2] = "chair"
    feats = np.stack([ENC.word_vector(w) for w in label.ravel()]).astype(np.float32)
    cells = MapCells(cell=np.arange(1600), features=feats, weight=np.ones(1600, np.float32),
                     count=np.ones(1600, np.int32), level=np.zeros(1600, np.int16))
    path = tmp_path_factory.mktemp("q") / "vlmap.zarr"
    write_map(path, artifact_attrs("vlmap", FORMAT_VERSION, "vlmap", "x", encoder=ENC.identity()), GRID,
              Lattice(GRID, 0.0, 0.0, 2.0, 0.1), cells, tile_cells=16)
    return path


def _query(map_path, **kw):
    navigable = kw.pop("navigable", None)
    return MapQuery(SemanticMap(map_path), ENC, QueryParams(min_candidate_area_m2=0.05, **kw), navigable=navigable)


def test_wins_and_heatmap(map_path):
    q = _query(map_path)
    r = q.query("chair")
    expect = np.zeros((40, 40), bool)
    expect[5:10, 5:10] = expect[30:34, 30:34] = True
    expect[35, 2] = True
    assert (r.wins == expect).all()
    v_chair, v_bg = ENC.word_vector("chair"), ENC.word_vector("background")
    s_bg = float(v_chair @ v_bg)
    p_chair = 1.0 / (1.0 + 4 * math.exp((s_bg - 1.0) / 0.1))  # 4 background prompts, all 'background' for the oracle
    p_bg_cell = 1.0 / (1.0 + 4 * math.exp((1.0 - s_bg) / 0.1))
    assert r.heatmap[7, 7] == pytest.approx(p_chair, rel=1e-3)
    assert r.heatmap[0, 0] == pytest.approx(p_bg_cell, rel=1e-2, abs=1e-6)
    assert r.background == ["other", "floor", "wall", "ceiling"] and r.temperature == 0.1


def test_candidates_sorted_by_distance_with_angles(map_path):
    q = _query(map_path)
    r = q.query("chair", pose=(0.05, 3.95, 0.0))  # the centre of cell (0, 0), facing east
    assert [c.area_m2 for c in r.candidates] == pytest.approx([0.25, 0.16])  # the 1-cell chair is too small
    a, b = r.candidates
    assert (a.obj_id, b.obj_id) == (1, 2)
    assert a.center_rc == (7, 7) and a.nearest_xy == pytest.approx((0.55, 3.45))
    assert a.distance_m == pytest.approx(math.hypot(0.5, 0.5))
    assert a.angle_rad == pytest.approx(-math.pi / 4)  # south-east of the pose: to the right
    assert b.distance_m == pytest.approx(math.hypot(3.0, 3.0))
    assert a.score > 0.99 and a.bbox_rc == (5, 5, 10, 10)
    r2 = q.query("chair", pose=(0.05, 3.95, -math.pi / 4))
    assert r2.candidates[0].angle_rad == pytest.approx(0.0, abs=1e-9)
    # from the far corner the small chair is nearer
    r3 = q.query("chair", pose=(3.95, 0.05, math.pi))
    assert r3.candidates[0].center_rc in {(31, 31), (31, 32), (32, 31), (32, 32)}
    # without a pose: by mass (score x area), the big chair first, no distances
    r4 = q.query("chair")
    assert r4.candidates[0].center_rc == (7, 7) and r4.candidates[0].distance_m is None


def test_absent_and_background_queries(map_path):
    q = _query(map_path)
    assert q.query("sofa").candidates == []
    r = q.query("floor")  # the same feature as every background prompt: they are left out
    assert r.background == [] and r.wins.all()
    json.dumps(q.query("table", pose=(1, 1, 0)).to_json())


def test_approach_points_and_grid_checks(map_path):
    nav = np.zeros((40, 40), bool)
    nav[:, 20] = True
    q = _query(map_path, navigable=nav)
    c = q.query("table").candidates[0]
    assert c.center_rc == (22, 9) and c.approach_xy == pytest.approx(GRID.cell_to_world(np.array([22, 20])))
    # equally near navigable cells on both sides (3 cells left, 3 right): the first in row-major order wins
    nav = np.zeros((40, 40), bool)
    nav[22, [6, 12]] = nav[25, 9] = True
    c = _query(map_path, navigable=nav).query("table").candidates[0]
    assert c.approach_xy == pytest.approx(GRID.cell_to_world(np.array([22, 6])))
    nav[22, 6] = False  # (22, 12) and (25, 9) are both 3 cells away: (22, 12) comes first row-major
    c = _query(map_path, navigable=nav).query("table").candidates[0]
    assert c.approach_xy == pytest.approx(GRID.cell_to_world(np.array([22, 12])))
    with pytest.raises(LineageError, match="does not match the map's grid"):
        _query(map_path, navigable=np.zeros((5, 5), bool))


def test_encoder_mismatch_is_refused(map_path):
    with pytest.raises(ArtifactError, match="map built with encoder 'oracle' \\(dim 64\\), query encoder is 'oracle' \\(dim 512\\)"):
        MapQuery(SemanticMap(map_path), OracleEncoder(dim=512), QueryParams())


def test_parse_pose():
    assert parse_pose("1, 2.5,-0.5") == (1.0, 2.5, -0.5)
    with pytest.raises(InputDataError, match="field --pose: got '1,2' \\(expected x,y,yaw in metres, metres, radians"):
        parse_pose("1,2")
    x, y, yaw = parse_pose("1,2,90", degrees=True)
    assert (x, y) == (1.0, 2.0) and abs(yaw - np.pi / 2) < 1e-12
    with pytest.raises(InputDataError, match="expected finite x,y,yaw in metres, metres, degrees"):
        parse_pose("1,nan,0", degrees=True)


def test_pictures(map_path, tmp_path):
    r = _query(map_path).query("chair", pose=(2.0, 2.0, 1.0))
    png = render_query(r, tmp_path / "q.png")
    img = cv2.imread(str(png))
    assert img.shape[0] > 300 and img.shape[2] == 3
    assert cv2.imread(str(render_map_pca(map_path, tmp_path / "pca.png"))) is not None


def test_low_rank_scoring_gives_the_exact_wins_and_candidates(tmp_path):
    rng = np.random.default_rng(3)
    words = ["chair", "table", "bed", "background"]
    table = np.stack([ENC.word_vector(w) for w in words]).astype(np.float32)
    label = rng.integers(0, 4, 1600)
    label[:400] = 3
    feats = table[label] + 0.05 * rng.standard_normal((1600, 64)).astype(np.float32)
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    cells = MapCells(cell=np.arange(1600), features=feats, weight=np.ones(1600, np.float32),
                     count=np.ones(1600, np.int32), level=np.zeros(1600, np.int16))
    path = tmp_path / "vlmap.zarr"
    write_map(path, artifact_attrs("vlmap", FORMAT_VERSION, "vlmap", "x", encoder=ENC.identity()), GRID,
              Lattice(GRID, 0.0, 0.0, 2.0, 0.1), cells, tile_cells=16)
    exact = MapQuery(SemanticMap(path), ENC, QueryParams(query_rank=0))
    low = MapQuery(SemanticMap(path), ENC, QueryParams(query_rank=3, query_lowrank_min_cells=10))
    for text in ("chair", "bed", "red table"):
        a, b = exact.query(text, (1.0, 1.0, 0.0)), low.query(text, (1.0, 1.0, 0.0))
        assert a.wins.any() and (a.wins == b.wins).all()
        assert [c.center_rc for c in a.candidates] == [c.center_rc for c in b.candidates]
        can_win = a.heatmap >= 0.5
        np.testing.assert_allclose(b.heatmap[can_win], a.heatmap[can_win], rtol=1e-5)
        assert np.nanmax(b.heatmap[~can_win]) < 0.5
    assert low._lowrank is not None and exact._lowrank is None


def _table_over_chair(path):
    """A 2 x 2 m room of floor with a table (top at level 7 of 0.1 m) over cells 5:15 x 5:15 and a chair (level 3)
    under its middle, 8:12 x 8:12: the top-down map shows the table there, the voxels keep the chair below it."""
    grid = GridSpec(rows=20, cols=20, cell_size_m=0.1, origin_xy=(0.0, 2.0))
    lat = Lattice(grid, 0.0, 0.0, 1.0, 0.1)
    rows, cols = np.divmod(np.arange(400), 20)
    under = (rows >= 5) & (rows < 15) & (cols >= 5) & (cols < 15)
    chair = (rows >= 8) & (rows < 12) & (cols >= 8) & (cols < 12)
    vox = [(c, 0, "floor") for c in np.flatnonzero(~chair)]  # floor seen everywhere but under the chair
    vox += [(c, 3, "chair") for c in np.flatnonzero(chair)] + [(c, 7, "table") for c in np.flatnonzero(under)]
    vox.sort(key=lambda v: (v[0], v[1]))
    cell = np.array([v[0] for v in vox])
    level = np.array([v[1] for v in vox])
    feats = np.stack([ENC.word_vector(v[2]) for v in vox]).astype(np.float16)
    top = np.r_[cell[1:] != cell[:-1], True]  # each cell's last (highest) voxel
    cells = MapCells(cell=cell[top], features=feats[top], weight=np.ones(400, np.float32),
                     count=np.ones(400, np.int32), level=level[top].astype(np.int16))
    voxels = MapVoxels(key=np.stack([cell // 20, cell % 20, level], axis=1).astype(np.int16), features=feats,
                       weight=np.ones(len(vox), np.float32), count=np.ones(len(vox), np.int32))
    write_map(path, artifact_attrs("cfmap", FORMAT_VERSION, "cfmap", "x", encoder=ENC.identity()), grid, lat, cells,
              tile_cells=8, voxels=voxels)
    return chair.reshape(20, 20)


def test_levels_max_finds_the_chair_under_the_table_that_top_misses(tmp_path):
    chair = _table_over_chair(tmp_path / "cfmap.zarr")
    smap = SemanticMap(tmp_path / "cfmap.zarr")
    top = MapQuery(smap, ENC, QueryParams(levels="top")).query("chair")
    best = MapQuery(smap, ENC, QueryParams(levels="max")).query("chair")
    assert top.levels == "top" and not top.wins.any() and top.candidates == []  # the table hides it
    assert best.levels == "max" and (best.wins == chair).all() and len(best.candidates) == 1
    c = best.candidates[0]
    assert chair[c.center_rc] and c.area_m2 == pytest.approx(16 * 0.01)
    assert best.to_json()["levels"] == "max"
    # the table is found by both (its top level is its best level); heatmaps agree wherever the top level is best
    t_top, t_max = (MapQuery(smap, ENC, QueryParams(levels=lv)).query("table") for lv in ("top", "max"))
    assert (t_top.wins == t_max.wins).all() and t_top.wins.sum() == 100
    np.testing.assert_allclose(t_max.heatmap[~chair], t_top.heatmap[~chair], rtol=1e-5)


def test_levels_max_on_a_map_without_voxels_scores_its_single_level(map_path):
    q = _query(map_path, levels="max")
    assert q.levels == "top"  # a vlmap keeps one level per cell
    assert (q.query("chair").wins == _query(map_path).query("chair").wins).all()


def test_the_first_query_reads_fp16_chunks_and_later_ones_one_fp32_copy(map_path):
    q = _query(map_path)
    first = q.query("table")
    assert q._f32 is None  # one query: no fp32 copy of the map
    again = q.query("table")
    assert q._f32 is not None and q._f32.dtype == np.float32 and q._f32.shape == (1600, 64)
    assert (first.wins == again.wins).all() and first.wins.sum() == 50
    np.testing.assert_allclose(first.heatmap, again.heatmap, rtol=1e-6)
    np.testing.assert_allclose(q.scores("table"), q._f32 @ q.text_features(["table"])[0], rtol=1e-6)


# ----------------------------------------------------------------------------- tile by tile (a map of many tiles)


@pytest.fixture(scope="module")
def tiled_map(tmp_path_factory):
    from tests.fixtures.tiled_maps import write_tiled_map

    return write_tiled_map(tmp_path_factory.mktemp("tiled") / "vlmap.zarr")


def _whole_array_answer(path, text, params):
    """The query's heatmap and winning cells computed from the whole (N,D) feature array at once, in numpy."""
    from tests.fixtures.tiled_maps import ENC as TENC

    smap = SemanticMap(path)
    f = smap.features()  # the whole array
    q = np.asarray(TENC.encode_text([text]), np.float32)[0]
    bg = np.asarray(TENC.encode_text(list(params.background)), np.float32)
    bg = bg[bg @ q <= 0.99]
    s, sb = f @ q, f @ bg.T
    t = np.float32(params.temperature or TENC.identity().get("temperature") or 0.1)
    lse = np.log(np.exp(sb / t).sum(axis=1))
    prob = 1.0 / (1.0 + np.exp(np.clip(lse - s / t, -80, 80)))
    heat = np.full(smap.grid.rows * smap.grid.cols, np.nan, np.float32)
    heat[smap.cell] = prob
    wins = np.zeros(smap.grid.rows * smap.grid.cols, bool)
    wins[smap.cell[(s > sb.max(axis=1)) & (prob >= params.min_probability)]] = True
    return heat.reshape(smap.grid.rows, smap.grid.cols), wins.reshape(smap.grid.rows, smap.grid.cols)


def test_a_query_read_block_by_block_equals_the_whole_array_and_the_held_paths(tiled_map, monkeypatch):
    from tests.fixtures.tiled_maps import ENC as TENC
    from tests.fixtures.tiled_maps import chunk_reads, chunks_of

    streamed = MapQuery(SemanticMap(tiled_map), TENC, QueryParams(hold_features_mb=0, query_rank=0))
    held = MapQuery(SemanticMap(tiled_map), TENC, QueryParams(query_rank=0))
    for text in ("chair", "table", "bed", "lamp"):
        with chunk_reads(monkeypatch) as reads:
            a = streamed.query(text, (1.0, 1.0, 0.5))
        # every feature chunk read once, in pieces of one chunk (never the array at once)
        assert reads["top/features"] == chunks_of(tiled_map, "top/features")
        assert len(set(reads.keys_read)) == len(reads.keys_read)
        b = held.query(text, (1.0, 1.0, 0.5))  # from its second query on: the whole fp32 array in memory
        heat, wins = _whole_array_answer(tiled_map, text, streamed.params)
        np.testing.assert_allclose(a.heatmap, heat, rtol=0, atol=2e-6)
        np.testing.assert_allclose(b.heatmap, heat, rtol=0, atol=2e-6)
        assert (a.wins == wins).all() and (b.wins == wins).all()
        assert [asdict_c(c) for c in a.candidates] == [asdict_c(c) for c in b.candidates]
    assert held._f32 is not None and streamed._f32 is None
    assert [c.center_rc for c in streamed.query("chair").candidates] == [(29, 34), (117, 189)]


def asdict_c(c):
    """A candidate's fields, scores rounded to float32 precision."""
    from dataclasses import asdict

    d = asdict(c)
    d["score"] = round(d["score"], 5)
    return d


def test_a_region_query_reads_only_the_tiles_it_meets_and_answers_as_the_floor_does_there(tiled_map, monkeypatch):
    from pipeline.region import Region, region_window
    from tests.fixtures.tiled_maps import ENC as TENC
    from tests.fixtures.tiled_maps import chunk_reads

    smap = SemanticMap(tiled_map)
    floor = MapQuery(smap, TENC, QueryParams(hold_features_mb=0)).query("chair")
    region = Region(-1.0, 2.5, 1.0, 4.5)  # around the first chair (rows 20..40, cols 25..45 of 5 cm cells)
    win = region_window(smap.grid, region)
    q = MapQuery(SemanticMap(tiled_map), TENC, QueryParams(hold_features_mb=0))
    with chunk_reads(monkeypatch) as reads:
        r = q.query("chair", region=region)
    # exactly the feature chunks holding the rows of the tiles the window meets
    chunk = SemanticMap(tiled_map).group["top"]["features"].chunks[0]
    want = {f"top/features/c/{k}/0" for s, e in smap.row_ranges(win) for k in range(s // chunk, (e - 1) // chunk + 1)}
    got = {k for k in reads.keys_read if k.startswith("top/features/")}
    assert got == want and len(want) < len(list((tiled_map / "top/features/c").rglob("*/*")))
    assert "top/index" not in reads
    assert r.grid == win.grid(smap.grid) and r.heatmap.shape == win.shape and r.region == region
    np.testing.assert_allclose(r.heatmap, floor.heatmap[win.slices], rtol=0, atol=2e-6)
    assert [c.center_xy for c in r.candidates] == [floor.candidates[0].center_xy]
    assert r.to_json()["region"] == {"x0": -1.0, "y0": 2.5, "x1": 1.0, "y1": 4.5}
    # the held path gives the same answer
    q.query("chair")
    held = MapQuery(SemanticMap(tiled_map), TENC, QueryParams())
    held.query("bed")
    held.query("bed")
    assert held._f32 is not None
    np.testing.assert_allclose(held.query("chair", region=region).heatmap, r.heatmap, rtol=0, atol=2e-6)


@pytest.mark.parametrize("box, message", [
    ((20.0, 0.0, 30.0, 5.0), "field region: x 20..30 m, y 0..5 m lies outside the floor's grid (expected a box "
                             "meeting x -2.00..9.50 m, y -2.50..5.00 m)"),
])
def test_a_region_off_the_grid_is_refused_naming_it(tiled_map, box, message):
    from pipeline.region import Region
    from tests.fixtures.tiled_maps import ENC as TENC

    with pytest.raises(InputDataError) as err:
        MapQuery(SemanticMap(tiled_map), TENC, QueryParams()).query("chair", region=Region(*box))
    assert str(err.value) == message


def test_open_queries_are_cached_up_to_a_bound(map_path):
    """An evaluation opens each scene's maps once and many scenes in one process: the cache keeps the most recently
    used queries only (each holds its map's features), and a repeated open returns the cached one."""
    from pipeline.config import Params
    from pipeline.maps import query

    query._CACHE.clear()
    params = [Params.model_validate({"scenes": {}, "encoders": {"oracle": {"dim": 64}}})
              for _ in range(query.CACHE_SIZE + 3)]
    opened = [query.open_query(map_path, p) for p in params]
    assert len(query._CACHE) == query.CACHE_SIZE
    assert query.open_query(map_path, params[-1]) is opened[-1]  # kept: the same object
    assert query.open_query(map_path, params[0]) is not opened[0]  # dropped long ago: opened afresh
    assert np.array_equal(query.open_query(map_path, params[0]).query("chair").wins, opened[0].query("chair").wins)
    query._CACHE.clear()
