"""The annotation page's top-down layers, drawn for the window the page shows.

The page asks for a layer of a floor in a ``region`` (world metres) at most ``px`` pixels on its longer side: the
whole floor at a zoom that fits the screen, or a zoomed part at full resolution. The picture is painted from the
recon's stored tiles (128-cell zarr chunks) that the region meets, one tile at a time, keeping every ``stride``-th
cell of the window (``stride`` = the fewest cells per pixel that fits ``px``), so memory is the picture plus one
tile whatever the floor's area. One pixel per cell (stride 1) when the window fits. Transparent where nothing was
observed; north up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.recon.store import OCCUPIED, UNKNOWN
from pipeline.region import Window

LAYERS = ("color", "height", "occupancy", "navigable", "rooms")
HEIGHT_BINS_M = np.linspace(0.0, 20.0, 2001)  # 1 cm bins: the brightest height, a percentile of the floor's heights


@dataclass(frozen=True)
class Picture:
    """A layer's ``rgba`` ``(h, w, 4)`` uint8 of the cells ``window`` of the floor's grid, one pixel per ``stride``
    cells; ``extent_xy`` = (x0, x1, y0, y1) metres that the picture covers."""

    rgba: np.ndarray
    window: Window
    stride: int
    extent_xy: tuple[float, float, float, float]


def stride_for(window: Window, px: int | None) -> int:
    """Cells per pixel so that the window's longer side fits ``px`` pixels (1 when it does, or for None)."""
    if px is None:
        return 1
    return max(1, math.ceil(max(window.shape) / px))


def height_top(floor) -> float:
    """The 99th percentile of the floor's known heights (metres; 1 when none), to 1 cm, from its height tiles read
    one at a time (a histogram, never the whole grid)."""
    counts = np.zeros(len(HEIGHT_BINS_M) - 1, np.int64)
    for tile in floor.tile_windows():
        h = tile.height
        h = h[np.isfinite(h)]
        counts += np.histogram(np.clip(h, HEIGHT_BINS_M[0], HEIGHT_BINS_M[-1]), HEIGHT_BINS_M)[0]
    if not counts.sum():
        return 1.0
    k = int(np.searchsorted(np.cumsum(counts), 0.99 * counts.sum()))
    return float(HEIGHT_BINS_M[k + 1])


def paint(floor, name: str, window: Window, stride: int, *, top_m: float = 1.0, rooms: list[dict] = ()) -> Picture:
    """Layer ``name`` of ``floor`` (recon's :class:`~pipeline.recon.store.FloorGrids`) in ``window``, one pixel per
    ``stride`` cells; ``top_m`` the height drawn brightest, ``rooms`` the floor's rooms (``polygon`` metres) for the
    rooms layer."""
    if name not in LAYERS:
        raise InputDataError(f"unknown layer {name!r}", field="layer", expected=f"one of {list(LAYERS)}")
    h, w = -(-window.shape[0] // stride), -(-window.shape[1] // stride)
    rgba = np.zeros((h, w, 4), np.uint8)
    for tile in floor.tile_windows(window):
        # the kept cells of this tile: those whose offset from the window's corner is a multiple of the stride
        part = tile.cells
        r_keep = np.arange(-(-(part.r0 - window.r0) // stride) * stride + window.r0, part.r1, stride)
        c_keep = np.arange(-(-(part.c0 - window.c0) // stride) * stride + window.c0, part.c1, stride)
        if not len(r_keep) or not len(c_keep):
            continue
        out = rgba[(r_keep[0] - window.r0) // stride:(r_keep[-1] - window.r0) // stride + 1,
                   (c_keep[0] - window.c0) // stride:(c_keep[-1] - window.c0) // stride + 1]
        out[...] = _tile_rgba(tile, name, top_m, rooms)[np.ix_(r_keep - part.r0, c_keep - part.c0)]
    g = floor.grid
    x0, y1 = g.origin_xy
    s = g.cell_size_m
    extent = (x0 + window.c0 * s, x0 + (window.c0 + w * stride) * s, y1 - (window.r0 + h * stride) * s,
              y1 - window.r0 * s)
    return Picture(rgba, window, stride, extent)


def _tile_rgba(tile, name: str, top_m: float, rooms) -> np.ndarray:
    """``(h, w, 4)`` uint8 of one tile's cells (a :class:`~pipeline.recon.store.WindowGrids`)."""
    shape = tile.grid.rows, tile.grid.cols
    rgba = np.zeros((*shape, 4), np.uint8)
    if name == "color":
        rgba[..., :3] = tile.color
        known = tile.occupancy != UNKNOWN
    elif name == "height":
        height = tile.height
        v = np.clip(np.nan_to_num(height) / max(top_m, 1e-6), 0, 1)
        rgba[..., :3] = cv2.applyColorMap((v * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1]
        known = np.isfinite(height)
    elif name == "occupancy":
        occ = tile.occupancy
        rgba[..., :3] = np.where((occ == OCCUPIED)[..., None], [40, 40, 40], [235, 235, 235])
        known = occ != UNKNOWN
    elif name == "navigable":
        rgba[..., :3] = np.where(tile.navigable[..., None], [120, 200, 120], [200, 200, 200])
        known = tile.occupancy != UNKNOWN
    else:  # rooms: each room outline filled in its own colour
        from pipeline.goals.objects import rasterize_polygons

        lab = rasterize_polygons([np.asarray(r["polygon"]) for r in rooms], tile.grid, list(range(1, len(rooms) + 1)))
        palette = np.array([[0, 0, 0], *[hue(i, len(rooms)) for i in range(len(rooms))]], np.uint8)
        rgba[..., :3] = palette[lab]
        known = lab > 0
    rgba[..., 3] = np.where(known, 255, 0)
    return rgba


def hue(i: int, n: int) -> list[int]:
    """The ``i``-th of ``n`` room colours, RGB."""
    hsv = np.array([[[int(180 * i / max(n, 1)), 120, 230]]], np.uint8)
    return [int(v) for v in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]]
