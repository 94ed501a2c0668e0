"""North-up pictures of semantic maps and queries (PNG; never artifacts).

- :func:`render_query`: recon's colour map, the query's heatmap blended over the cells where the query's
  probability reaches 0.3 (turbo: blue = 0, red = 1; strongest where the query wins, so the rest of the map
  keeps its colours), white outlines around candidates, numbered markers at their centres (1 = first in the
  result's order), the pose as an arrow; a colour bar and a legend below. A query of every floor of a building
  (:class:`~pipeline.maps.floors.FloorsResult`) draws each floor so, side by side, lowest first, titled with its
  floor (candidate numbers are those of the combined list).
- :func:`render_map_pca`: one floor's map features projected on their first three principal axes as
  RGB, a quick look at what the map separates.

A building's pictures (each floor of a query of every floor, each floor's features) also have metre axes along
their left and bottom edges; a single-floor scene's are as they always were.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipeline.maps.floors import FloorsResult
from pipeline.maps.query import QueryResult
from pipeline.maps.store import SemanticMap
from pipeline.pictures import add_colorbar, add_legend, add_metre_axes, add_scale_bar, colorize, write_png
from pipeline.region import Region, Window, region_window, whole

HEAT_FLOOR = 0.3  # cells below this probability keep the colour map untinted


def _crop_box(mask: np.ndarray, margin: int = 10) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask)
    if not len(rows):
        return 0, mask.shape[0], 0, mask.shape[1]
    return (max(int(rows.min()) - margin, 0), min(int(rows.max()) + 1 + margin, mask.shape[0]),
            max(int(cols.min()) - margin, 0), min(int(cols.max()) + 1 + margin, mask.shape[1]))


def _upscale(img: np.ndarray, min_side: int = 640) -> tuple[np.ndarray, int]:
    k = max(1, int(np.ceil(min_side / max(min(img.shape[:2]), 1))))
    k = min(k, 8)
    return cv2.resize(img, None, fx=k, fy=k, interpolation=cv2.INTER_NEAREST), k


def render_query(result: QueryResult | FloorsResult, out_png: str | Path, *, crop: bool = True) -> Path:
    """Write the query picture (a building's floors side by side); returns its path."""
    if isinstance(result, FloorsResult):
        images = [_query_image(r, crop, title_floor=True) for r in result.floors]
        height = max(img.shape[0] for img in images)
        gap = np.full((height, 12, 3), 255, np.uint8)
        padded = [np.concatenate([img, np.full((height - img.shape[0], img.shape[1], 3), 255, np.uint8)])
                  for img in images]
        return write_png(Path(out_png), np.concatenate([x for img in padded for x in (img, gap)][:-1], axis=1))
    return write_png(Path(out_png), _query_image(result, crop))


def _query_image(result: QueryResult, crop: bool, *, title_floor: bool = False) -> np.ndarray:
    """The picture of one floor's query, ``(H, W, 3)`` uint8."""
    g = result.grid
    heat = result.heatmap
    observed = np.isfinite(heat)
    base = result.color if result.color is not None else np.zeros((g.rows, g.cols, 3), np.uint8)
    base = base.astype(np.float32)
    unknown = base.sum(axis=-1) == 0
    base[unknown] = 235.0
    hm = colorize(np.nan_to_num(heat), 0.0, 1.0).astype(np.float32)
    # low-probability cells keep most of the colour map; winning cells show the heatmap strongly
    prob = np.nan_to_num(heat, nan=0.0)
    shade = np.clip((prob - HEAT_FLOOR) / (1.0 - HEAT_FLOOR), 0.0, 1.0)
    alpha = np.where(result.wins, 0.85, 0.7 * shade)[..., None] * observed[..., None]
    img = (base * (1 - alpha) + hm * alpha).clip(0, 255).astype(np.uint8)
    r0, r1, c0, c1 = _crop_box(observed | ~unknown) if crop else (0, g.rows, 0, g.cols)
    img, k = _upscale(np.ascontiguousarray(img[r0:r1, c0:c1]))
    for c in result.candidates:
        if result.labels is not None:
            m = (result.labels[r0:r1, c0:c1] == c.label).astype(np.uint8)
            m = cv2.resize(m, None, fx=k, fy=k, interpolation=cv2.INTER_NEAREST)
            contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(img, contours, -1, (255, 255, 255), 2)
        p = (int((c.center_rc[1] - c0 + 0.5) * k), int((c.center_rc[0] - r0 + 0.5) * k))
        cv2.circle(img, p, 9, (0, 0, 0), -1)
        cv2.putText(img, str(c.obj_id), (p[0] - 5, p[1] + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                    cv2.LINE_AA)
    if result.pose is not None:
        x, y, yaw = result.pose
        pc = ((x - g.origin_xy[0]) / g.cell_size_m - c0) * k, ((g.origin_xy[1] - y) / g.cell_size_m - r0) * k
        tip = pc[0] + 28 * np.cos(yaw), pc[1] - 28 * np.sin(yaw)  # north-up: +y is up the image
        cv2.circle(img, (int(pc[0]), int(pc[1])), 7, (255, 0, 255), -1)
        cv2.arrowedLine(img, (int(pc[0]), int(pc[1])), (int(tip[0]), int(tip[1])), (255, 0, 255), 3, tipLength=0.35)
    img = add_scale_bar(img, g.cell_size_m / k)
    if title_floor or result.region is not None:  # one floor of a building, or a region: where it lies
        img = _axes(img, g, r0, c0, k)
    img = add_colorbar(img, 0.0, 1.0, f"P('{result.text}' vs background)")
    legend = [((255, 255, 255), "candidate outline"), ((0, 0, 0), "n = candidate rank")]
    if result.pose is not None:
        legend.append(((255, 0, 255), "pose and heading"))
    img = add_legend(img, legend + [((235, 235, 235), "unobserved")])
    where = f"{result.floor_name}, " if title_floor else ""
    title = f"{result.artifact}: '{result.text}'  ({where}{len(result.candidates)} candidates)"
    band = np.full((26, img.shape[1], 3), 255, np.uint8)
    cv2.putText(band, title, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([band, img], axis=0)


def render_map_pca(map_path: str | Path, out_png: str | Path, *, crop: bool = True, floor: int = 0,
                   region: Region | None = None) -> Path:
    """Features of floor ``floor`` (an index, lowest first) of a map as RGB (first three principal components of the
    cells drawn); unobserved cells white.

    Read block by block (:meth:`~pipeline.maps.store.SemanticMap.blocks`), twice (the principal axes from every
    k-th cell and the mean, then each block projected), so memory is one stored chunk's features plus a few bytes
    per cell drawn. ``region`` (world metres) draws only its cells,
    reading only the tiles it meets (an InputDataError naming ``--region`` when it misses the grid); without it,
    ``crop`` trims the picture to the observed cells plus a margin."""
    smap = SemanticMap(map_path, floor)
    g = smap.grid
    window = region_window(g, region) if region is not None else whole(g)
    step = max(1, sum(e - s for s, e in smap.row_ranges(window)) // 20000)
    total, n, box = np.zeros(smap.dim), 0, None
    s_sum, s_outer, s_n = np.zeros(smap.dim), np.zeros((smap.dim, smap.dim)), 0
    for rows, cells, feats in smap.blocks(window):  # pass 1: the mean, every step-th cell's moments, the box
        f = feats.astype(np.float64)
        total += f.sum(axis=0)
        picked = f[(np.arange(n, n + len(f)) % step) == 0]
        s_sum, s_outer, s_n = s_sum + picked.sum(axis=0), s_outer + picked.T @ picked, s_n + len(picked)
        n += len(f)
        r, c = np.divmod(cells, g.cols)
        box = _union(box, (int(r.min()), int(r.max()) + 1, int(c.min()), int(c.max()) + 1))
    if region is None and crop and box is not None:
        window = Window(max(box[0] - 10, 0), min(box[1] + 10, g.rows), max(box[2] - 10, 0), min(box[3] + 10, g.cols))
    h, w = window.shape
    img = np.full((h * w, 3), 255, np.uint8)
    if n >= 3:
        mean = total / n
        vt = _principal_axes(s_outer, s_sum, s_n, mean)
        where, proj = [], []
        for _, cells, feats in smap.blocks(window):  # pass 2: each block projected on the axes
            r, c = np.divmod(cells, g.cols)
            where.append((r - window.r0) * w + (c - window.c0))
            proj.append(((feats.astype(np.float64) - mean) @ vt[:3].T).astype(np.float32))
        p = np.concatenate(proj)
        lo, hi = np.percentile(p, 1, axis=0), np.percentile(p, 99, axis=0)
        img[np.concatenate(where)] = ((p - lo) / np.maximum(hi - lo, 1e-9) * 255).clip(0, 255).astype(np.uint8)
    img, k = _upscale(img.reshape(h, w, 3))
    img = add_scale_bar(img, g.cell_size_m / k)
    if len(smap.floors) > 1 or region is not None:
        img = _axes(img, g, window.r0, window.c0, k)
    return write_png(Path(out_png), img)


def _principal_axes(outer: np.ndarray, total: np.ndarray, n: int, mean: np.ndarray, k: int = 3) -> np.ndarray:
    """``(k, D)`` first principal axes of ``n`` samples about ``mean`` from their moments ``outer`` = sum x x^T and
    ``total`` = sum x (the scatter matrix's leading eigenvectors, each signed so its largest entry is positive)."""
    scatter = outer - np.outer(total, mean) - np.outer(mean, total) + n * np.outer(mean, mean)
    _, vectors = np.linalg.eigh(scatter)
    axes = vectors[:, ::-1][:, :k].T
    return axes * np.sign(axes[np.arange(len(axes)), np.abs(axes).argmax(axis=1)])[:, None]


def _union(a: tuple[int, int, int, int] | None, b: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
    """The bounding box ``(r0, r1, c0, c1)`` of two boxes (``a`` None: ``b``)."""
    return b if a is None else (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))


def _axes(img: np.ndarray, g, r0: int, c0: int, k: int) -> np.ndarray:
    """Metre axes on a picture of grid ``g`` cropped at cell (``r0``, ``c0``) and upscaled ``k`` times."""
    return add_metre_axes(img, g.origin_xy[0] + c0 * g.cell_size_m, g.origin_xy[1] - r0 * g.cell_size_m,
                          k / g.cell_size_m)
