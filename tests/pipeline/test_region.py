"""Regions in world metres -> windows of grid cells and the stored tiles they meet (pipeline/region.py)."""

import pytest

from pipeline.errors import InputDataError
from pipeline.geometry import GridSpec
from pipeline.region import Region, Window, parse_region, region_window, whole

GRID = GridSpec(rows=300, cols=200, cell_size_m=0.05, origin_xy=(-5.0, 10.0))  # x -5..5, y -5..10


def test_a_region_covers_the_cells_it_touches_clipped_to_the_grid():
    assert region_window(GRID, None) == whole(GRID) == Window(0, 300, 0, 200)
    # x 0..1 m is columns 100..120, y 9..10 m rows 0..20; a box ending inside a cell keeps that cell
    assert region_window(GRID, Region(0.0, 9.0, 1.0, 10.0)) == Window(0, 20, 100, 120)
    assert region_window(GRID, Region(0.01, 9.0, 1.01, 9.99)) == Window(0, 20, 100, 121)
    assert region_window(GRID, Region(-100.0, -100.0, 100.0, 100.0)) == whole(GRID)
    win = region_window(GRID, Region(-4.0, 0.0, 0.0, 2.0))
    sub = win.grid(GRID)
    assert sub.extent_xy == pytest.approx((-4.0, 0.0, 0.0, 2.0))  # the window's grid keeps world metres
    assert (sub.rows, sub.cols) == win.shape == (40, 80)


def test_a_window_walks_the_tiles_it_meets_and_their_parts_inside_it():
    parts = list(Window(100, 140, 120, 260).tiles(128))
    assert [(tr, tc) for tr, tc, _ in parts] == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]
    assert parts[0][2] == Window(100, 128, 120, 128) and parts[-1][2] == Window(128, 140, 256, 260)
    assert sum(p.shape[0] * p.shape[1] for _, _, p in parts) == 40 * 140
    assert parts[4][2].within(Window(100, 140, 120, 260)) == Window(28, 40, 8, 136)


@pytest.mark.parametrize("values, message", [
    ((1, 2, 0, 3), "field --region: x runs from 1 to 0: inverted"),
    ((0, 3, 1, 2), "field --region: y runs from 3 to 2: inverted"),
    ((0, 2, 0, 3), "field --region: x runs from 0 to 0: empty"),
    ((0, 1, 2), "field --region: got (0, 1, 2)"),
    ((0, 1, 2, float("nan")), "field --region: got 0 1 2 nan"),
    ("0,1,two,3", "field --region: got ['0', '1', 'two', '3']"),
])
def test_an_empty_inverted_or_malformed_region_is_refused_naming_the_option(values, message):
    with pytest.raises(InputDataError) as err:
        parse_region(values)
    assert str(err.value).startswith(message)
    assert "expected X0 Y0 X1 Y1: four numbers, metres in the world frame, with X0 < X1 and Y0 < Y1" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_region_off_the_grid_names_the_option_and_the_grid_extent():
    assert parse_region("1, 2 3,4") == Region(1.0, 2.0, 3.0, 4.0)
    with pytest.raises(InputDataError) as err:
        region_window(GRID, Region(5.0, 0.0, 8.0, 2.0), "--region")  # touches x = 5, the grid's east edge
    assert str(err.value) == ("field --region: x 5..8 m, y 0..2 m lies outside the floor's grid "
                              "(expected a box meeting x -5.00..5.00 m, y -5.00..10.00 m)")
