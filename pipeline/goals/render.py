"""North-up pictures of goals and routes on the recon colour map (``zipon render <scene> --what goals|routes``).

``goals``: every object footprint outlined (grey), goal footprints filled in a colour per goal with
their personalized names, landmark links (dashed) to the objects named in the landmark feedback.
``routes``: the same goals, plus each stored episode's FMM polyline with its start pose (a dot and
a heading tick). A scale bar and north arrow come from :mod:`pipeline.pictures`.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import ConfigError
from pipeline.geometry import GridSpec
from pipeline.goals.store import Goals
from pipeline.routes.store import Routes
from pipeline.pictures import add_scale_bar, label_colors, write_png

WHATS = ("goals", "routes")
SCALE = 3  # output pixels per grid cell


def _px(grid: GridSpec, xy: np.ndarray) -> np.ndarray:
    """World (x, y) -> integer pixel (u, v) of the upscaled image (``shift``-free)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    x0, y1 = grid.origin_xy
    u = (xy[:, 0] - x0) / grid.cell_size_m * SCALE
    v = (y1 - xy[:, 1]) / grid.cell_size_m * SCALE
    return np.round(np.stack([u, v], -1)).astype(np.int32)


def render_goals(recon_path, goals_path, routes_path, what: str, out_png, *, crop: bool = True) -> Path:
    """Draw goals (and routes) over the colour map; returns the PNG path."""
    from pipeline.recon import Recon

    if what not in WHATS:
        raise ConfigError(f"render --what {what!r}: expected one of {list(WHATS)}")
    recon = Recon(recon_path)
    goals = Goals(goals_path)
    grid = recon.grid
    base = recon.color.copy()
    base[~(recon.occupancy > 0)] = 255
    img = cv2.resize(base, (grid.cols * SCALE, grid.rows * SCALE), interpolation=cv2.INTER_NEAREST)
    img = (img.astype(np.float32) * 0.75 + 255 * 0.25).astype(np.uint8)  # lighten so overlays read
    box = _crop_box(recon.occupancy > 0, img.shape) if crop else (0, img.shape[0], 0, img.shape[1])
    colors = label_colors(np.arange(1, len(goals.goals) + 1)).reshape(-1, 3)
    for o in goals.objects.values():
        cv2.polylines(img, [_px(grid, o.footprint)], True, (90, 90, 90), 1, cv2.LINE_AA)
    overlay = img.copy()
    for g, col in zip(goals.goals, colors):
        for fp in g.footprints:
            cv2.fillPoly(overlay, [_px(grid, fp)], tuple(int(c) for c in col))
    img = cv2.addWeighted(overlay, 0.6, img, 0.4, 0)
    if what == "routes" and routes_path is not None:
        routes = Routes(routes_path)
        gcol = {g.id: tuple(int(c) for c in col) for g, col in zip(goals.goals, colors)}
        for e in routes.episodes:
            col = gcol.get(e.goal_id, (0, 0, 0))
            cv2.polylines(img, [_px(grid, e.path_xy)], False, col, 2, cv2.LINE_AA)
            s = _px(grid, e.start[:2])[0]
            tip = _px(grid, np.array(e.start[:2]) + 0.4 * np.array([np.cos(e.start[2]), np.sin(e.start[2])]))[0]
            cv2.circle(img, tuple(int(v) for v in s), 5, col, -1, cv2.LINE_AA)
            cv2.circle(img, tuple(int(v) for v in s), 5, (0, 0, 0), 1, cv2.LINE_AA)
            cv2.line(img, tuple(int(v) for v in s), tuple(int(v) for v in tip), (0, 0, 0), 2, cv2.LINE_AA)
    for g, col in zip(goals.goals, colors):
        c = _px(grid, g.mass_center)[0]
        for lm in g.landmarks:
            o = goals.objects.get(lm["object"])
            if o is not None:
                _dashed(img, c, _px(grid, o.mass_center)[0], (60, 60, 60))
        for fp in g.footprints:
            cv2.polylines(img, [_px(grid, fp)], True, (0, 0, 0), 2, cv2.LINE_AA)
        _label(img, g.name, c, box)
    title = f"{goals.scene}: {len(goals.goals)} goals" + (
        f", {len(Routes(routes_path).episodes)} verified routes" if what == "routes" and routes_path else "")
    if crop:
        img = np.ascontiguousarray(img[box[0]:box[1], box[2]:box[3]])
        img = np.ascontiguousarray(np.pad(img, ((26, 0), (0, 0), (0, 0)), constant_values=255))
    img = add_scale_bar(img, grid.cell_size_m / SCALE)
    cv2.putText(img, title, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return write_png(Path(out_png), img)


def _label(img: np.ndarray, text: str, at: np.ndarray, box: tuple[int, int, int, int]) -> None:
    """A white-boxed label centred above ``at``, kept inside ``box`` = (r0, r1, c0, c1)."""
    r0, r1, c0, c1 = box
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.42, 1)
    x = int(np.clip(int(at[0]) - w // 2, c0 + 2, max(c1 - w - 2, c0 + 2)))
    y = int(np.clip(int(at[1]) - 8, r0 + h + 4, r1 - 4))
    cv2.rectangle(img, (x - 2, y - h - 2), (x + w + 2, y + 3), (255, 255, 255), -1)
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)


def _dashed(img: np.ndarray, a: np.ndarray, b: np.ndarray, col, dash: int = 6) -> None:
    n = max(int(np.linalg.norm(b - a) // dash), 1)
    pts = np.linspace(a, b, n + 1).astype(int)
    for i in range(0, n, 2):
        cv2.line(img, tuple(map(int, pts[i])), tuple(map(int, pts[i + 1])), col, 1, cv2.LINE_AA)


def _crop_box(known: np.ndarray, shape, margin: int = 20) -> tuple[int, int, int, int]:
    rr, cc = np.nonzero(known)
    if rr.size == 0:
        return 0, shape[0], 0, shape[1]
    r0, r1 = max(rr.min() * SCALE - margin, 0), min((rr.max() + 1) * SCALE + margin, shape[0])
    c0, c1 = max(cc.min() * SCALE - margin, 0), min((cc.max() + 1) * SCALE + margin, shape[1])
    return int(r0), int(r1), int(c0), int(c1)
