"""Colour bars and legends on the PNG pictures, and query heatmaps that leave unlikely cells untinted."""

import cv2
import numpy as np

from pipeline.geometry import GridSpec
from pipeline.pictures import AXIS_BOTTOM, AXIS_LEFT, add_colorbar, add_legend, add_metre_axes, colorize


def test_colorbar_band_runs_the_colormap_from_low_to_high():
    img = np.zeros((50, 400, 3), np.uint8)
    out = add_colorbar(img, 0.0, 10.0, "depth (m)")
    assert out.shape == (96, 400, 3) and (out[:50] == 0).all()
    row = out[50 + 15]
    ramp = np.flatnonzero((row != 255).any(axis=1))  # the bar's columns (the label is above this row)
    lo, hi = colorize(np.array([[0.0, 1.0]]), 0.0, 1.0)[0]
    assert np.abs(row[ramp[-1] - 2].astype(int) - hi).max() < 40  # the right end is the top colour
    assert any(np.abs(row[x].astype(int) - lo).max() < 40 for x in ramp[:40])  # near the left, the bottom colour


def test_legend_wraps_and_draws_each_swatch():
    img = np.zeros((10, 200, 3), np.uint8)
    entries = [((255, 0, 0), "first entry"), ((0, 0, 255), "second entry"), ((0, 200, 0), "third")]
    out = add_legend(img, entries, title="legend")
    assert out.shape[0] > 10 + 22 + 20  # a title and more than one row at this width
    for colour, _ in entries:
        assert (out[10:] == colour).all(axis=-1).any(), colour


def test_query_picture_has_colorbar_and_keeps_unlikely_cells_untinted(tmp_path):
    from pipeline.maps.query import Candidate, QueryResult
    from pipeline.maps.render import render_query

    g = GridSpec(40, 40, 0.05, (0.0, 2.0))
    heat = np.full((40, 40), 0.1, np.float32)
    heat[10:20, 10:20] = 0.95
    wins = heat > 0.5
    labels = wins.astype(np.int32)
    color = np.full((40, 40, 3), 120, np.uint8)
    cand = Candidate(1, (0.75, 1.25), (0.75, 1.25), (0.75, 1.25), None, None, None, 0.25, 0.95, (15, 15),
                     (10, 10, 20, 20), label=1)
    res = QueryResult("sofa", "vlmap", g, heat, wins, [cand], None, ["other"], 0.1, 0.0, labels=labels, color=color)
    png = render_query(res, tmp_path / "q.png", crop=False)
    img = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
    k = 8  # 40 cells upscaled toward 640 px, at most 8 times
    top = 26
    # a cell with probability 0.1 keeps the colour map exactly; a winning cell is mostly heatmap red
    assert (img[top + 30 * k + 4, 30 * k + 4] == 120).all()
    red = colorize(np.array([[0.95]]), 0.0, 1.0)[0, 0].astype(int)
    assert np.abs(img[top + 12 * k + 4, 12 * k + 4].astype(int) - red).max() < 60
    assert img.shape[0] > top + 40 * k + 40  # colour bar and legend below the map


def test_metre_axes_tick_each_round_metre_where_it_lies():
    img = np.full((300, 600, 3), 200, np.uint8)
    out = add_metre_axes(img, -1.25, 9.0, 60.0)  # 60 px a metre: a tick every metre
    assert out.shape == (300 + AXIS_BOTTOM, 600 + AXIS_LEFT, 3) and (out[:300, AXIS_LEFT:] == 200).all()
    dark = (out < 100).all(axis=-1)
    for x in range(-1, 9):  # x from -1.25 to 8.75: ticks at -1 .. 8
        assert dark[302, AXIS_LEFT + round((x + 1.25) * 60)], x
    for y in range(5, 9):  # y from 9 (the top edge) down to 4 (the bottom edge): ticks at 5 .. 8 inside
        assert dark[round((9.0 - y) * 60), AXIS_LEFT - 3], y
    assert not dark[302, AXIS_LEFT + 30]  # no tick between two metres
    assert dark[305:, AXIS_LEFT:].any() and dark[:300, :AXIS_LEFT - 6].any()  # the labels
