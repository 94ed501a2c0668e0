"""Pictures of a map's features and of a region of it, read block by block (pipeline/maps/render.py)."""

import cv2
import numpy as np
import pytest

from pipeline.config import QueryParams
from pipeline.errors import InputDataError
from pipeline.maps.query import MapQuery
from pipeline.maps.render import render_map_pca, render_query
from pipeline.maps.store import SemanticMap
from pipeline.region import Region, region_window
from tests.fixtures.tiled_maps import ENC, chunk_reads, chunks_of, write_tiled_map


@pytest.fixture(scope="module")
def tiled_map(tmp_path_factory):
    return write_tiled_map(tmp_path_factory.mktemp("tiled") / "vlmap.zarr")


def test_the_whole_map_is_drawn_from_its_blocks_each_chunk_read_twice(tiled_map, tmp_path, monkeypatch):
    with chunk_reads(monkeypatch) as reads:
        img = cv2.imread(str(render_map_pca(tiled_map, tmp_path / "pca.png", crop=False)))
    assert reads["top/features"] == 2 * chunks_of(tiled_map, "top/features")  # the axes, then the projection
    assert "top/index" not in reads
    # 150 x 230 cells upscaled k = 5 (the shorter side reaches 640 px); the unobserved north-east block is white
    assert img.shape[:2] == (750, 1150)
    assert (img[60:310, 760:1100] == 255).all()  # (the north arrow stands in its corner)
    assert len(np.unique(img[400:700, 100:600].reshape(-1, 3), axis=0)) > 3  # objects and floor differ


def test_a_region_is_drawn_from_the_tiles_it_meets_only_with_its_metre_axes(tiled_map, tmp_path, monkeypatch):
    smap = SemanticMap(tiled_map)
    region = Region(5.0, -2.0, 9.0, 1.0)  # the south-east: rows 80..140, cols 140..220 of 5 cm cells
    win = region_window(smap.grid, region)
    with chunk_reads(monkeypatch) as reads:
        img = cv2.imread(str(render_map_pca(tiled_map, tmp_path / "part.png", region=region)))
    chunk = smap.group["top"]["features"].chunks[0]
    want = {k for s, e in smap.row_ranges(win) for k in range(s // chunk, (e - 1) // chunk + 1)}
    assert reads["top/features"] == 2 * len(want) < chunks_of(tiled_map, "top/features")
    # 60 x 80 cells at k = 8 (the most): 480 x 640 px, plus the metre axes' margins left and below
    assert 480 < img.shape[0] < 600 and 640 < img.shape[1] < 760
    assert (img[:480, -640:] != 255).any(axis=2).mean() > 0.9  # every cell of the region is observed


def test_a_region_query_picture_has_metre_axes_and_the_candidate(tiled_map, tmp_path):
    region = Region(-1.0, 2.5, 1.0, 4.5)
    r = MapQuery(SemanticMap(tiled_map), ENC, QueryParams()).query("chair", region=region)
    img = cv2.imread(str(render_query(r, tmp_path / "q.png", crop=False)))
    whole = cv2.imread(str(render_query(MapQuery(SemanticMap(tiled_map), ENC, QueryParams()).query("chair"),
                                        tmp_path / "w.png")))
    assert len(r.candidates) == 1 and img.shape != whole.shape


def test_a_region_off_the_map_is_refused_naming_the_option(tiled_map, tmp_path):
    with pytest.raises(InputDataError, match="field --region: x 20..30 m, y 0..5 m lies outside the floor's grid"):
        render_map_pca(tiled_map, tmp_path / "x.png", region=Region(20.0, 0.0, 30.0, 5.0))
    assert not (tmp_path / "x.png").exists()
