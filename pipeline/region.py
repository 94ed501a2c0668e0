"""A region of a floor in world metres and the window of grid cells it covers, read tile by tile.

Grids (``recon.zarr``) and maps (``vlmap.zarr`` / ``cfmap.zarr``) are stored in square spatial tiles that are
zarr chunks (recon: 128 cells; maps: ``maps.tile_cells``). A reader that shows a region (``zipon render
--region``, ``zipon query --region``, the annotation page's window, :class:`~pipeline.scene.MapView`) turns it into
a :class:`Window` of cells with :func:`region_window`, then walks :meth:`Window.tiles`, so it reads only the
chunks that intersect the window and holds one tile at a time.

``Region``: ``x0 < x1``, ``y0 < y1`` metres, world frame (x east, y north). A region covers the cells it
touches, clipped to the grid; one that touches no cell of the grid, or is empty or inverted, is an
:class:`~pipeline.errors.InputDataError` naming the option it came from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Sequence

from pipeline.errors import InputDataError
from pipeline.geometry import GridSpec

EDGE = 1e-6  # cells: how near a cells' edge a region's edge counts as on it


@dataclass(frozen=True)
class Region:
    """An axis-aligned box of the world, metres: x from ``x0`` to ``x1`` (east), y from ``y0`` to ``y1`` (north)."""

    x0: float
    y0: float
    x1: float
    y1: float

    def __str__(self) -> str:
        return f"x {self.x0:g}..{self.x1:g} m, y {self.y0:g}..{self.y1:g} m"


@dataclass(frozen=True)
class Window:
    """Cells ``[r0, r1) x [c0, c1)`` of a grid (ends excluded), north-up as the grid."""

    r0: int
    r1: int
    c0: int
    c1: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.r1 - self.r0, self.c1 - self.c0

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.r0, self.r1), slice(self.c0, self.c1)

    def grid(self, grid: GridSpec) -> GridSpec:
        """The grid of this window's cells: the same cells, its own origin (so world metres stay right)."""
        x0, y1 = grid.origin_xy
        return GridSpec(self.r1 - self.r0, self.c1 - self.c0, grid.cell_size_m,
                        (x0 + self.c0 * grid.cell_size_m, y1 - self.r0 * grid.cell_size_m))

    def tiles(self, tile: int) -> Iterator[tuple[int, int, "Window"]]:
        """``(tile_row, tile_col, part)`` for each ``tile``-cell tile of the grid that meets this window, row-major;
        ``part`` is the tile's cells inside the window (grid coordinates)."""
        for tr in range(self.r0 // tile, -(-self.r1 // tile)):
            for tc in range(self.c0 // tile, -(-self.c1 // tile)):
                yield tr, tc, Window(max(self.r0, tr * tile), min(self.r1, (tr + 1) * tile),
                                     max(self.c0, tc * tile), min(self.c1, (tc + 1) * tile))

    def within(self, outer: "Window") -> "Window":
        """This window's cells in the coordinates of ``outer`` (which holds it)."""
        return Window(self.r0 - outer.r0, self.r1 - outer.r0, self.c0 - outer.c0, self.c1 - outer.c0)

    def contains(self, row, col):
        """Whether cells ``(row, col)`` (arrays, grid coordinates) lie in the window."""
        return (row >= self.r0) & (row < self.r1) & (col >= self.c0) & (col < self.c1)


def whole(grid: GridSpec) -> Window:
    """Every cell of ``grid``."""
    return Window(0, grid.rows, 0, grid.cols)


def parse_region(values: Sequence[float] | str, option: str = "--region") -> Region:
    """``X0 Y0 X1 Y1`` (four numbers, or a string of them separated by commas or spaces) -> :class:`Region`;
    an InputDataError naming ``option`` when they are not four finite numbers with ``x0 < x1`` and ``y0 < y1``."""
    expected = "X0 Y0 X1 Y1: four numbers, metres in the world frame, with X0 < X1 and Y0 < Y1"
    if isinstance(values, str):
        values = [v for v in values.replace(",", " ").split() if v]
    try:
        x0, y0, x1, y1 = (float(v) for v in values)
    except (TypeError, ValueError):
        raise InputDataError(f"got {values!r}", field=option, expected=expected) from None
    if not all(map(math.isfinite, (x0, y0, x1, y1))):
        raise InputDataError(f"got {x0:g} {y0:g} {x1:g} {y1:g}", field=option, expected=expected)
    for lo, hi, axis in ((x0, x1, "x"), (y0, y1, "y")):
        if hi < lo:
            raise InputDataError(f"{axis} runs from {lo:g} to {hi:g}: inverted", field=option, expected=expected)
        if hi == lo:
            raise InputDataError(f"{axis} runs from {lo:g} to {hi:g}: empty", field=option, expected=expected)
    return Region(x0, y0, x1, y1)


def region_window(grid: GridSpec, region: Region | None, option: str = "--region") -> Window:
    """The cells of ``grid`` that ``region`` touches (the whole grid for None); an InputDataError naming
    ``option`` and the grid's extent when it touches none."""
    if region is None:
        return whole(grid)
    s = grid.cell_size_m
    gx0, gy1 = grid.origin_xy
    # cell (r, c) covers x in [gx0 + c s, gx0 + (c+1) s) and y in (gy1 - (r+1) s, gy1 - r s] (pipeline.geometry);
    # an edge within a millionth of a cell of a cells' edge lies on it (3.2 m / 0.05 m is 63.99999999 in floats)
    c0, c1 = math.floor((region.x0 - gx0) / s + EDGE), math.ceil((region.x1 - gx0) / s - EDGE)
    r0, r1 = math.floor((gy1 - region.y1) / s + EDGE), math.ceil((gy1 - region.y0) / s - EDGE)
    win = Window(max(r0, 0), min(r1, grid.rows), max(c0, 0), min(c1, grid.cols))
    if win.r0 >= win.r1 or win.c0 >= win.c1:
        x0, x1, y0, y1 = grid.extent_xy
        raise InputDataError(f"{region} lies outside the floor's grid", field=option,
                             expected=f"a box meeting x {x0:.2f}..{x1:.2f} m, y {y0:.2f}..{y1:.2f} m")
    return win
