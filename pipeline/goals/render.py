"""North-up pictures of goals and routes on the recon colour map (``zipon render <scene> --what goals|routes``).

``goals``: every object footprint outlined (grey), goal footprints filled in a colour per goal and
numbered at their mass centre (the legend below gives each number's personalized name and type, so
labels never collide or get clipped), landmark links (dashed) to the objects named in the landmark
feedback. ``routes``: the same goals, plus each stored episode's FMM polyline with its start pose (a
dot and a heading tick). :func:`render_episodes`: an evaluated episode's walked path over the same map.
A scale bar and north arrow come from :mod:`pipeline.pictures`.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import ConfigError
from pipeline.geometry import GridSpec
from pipeline.goals.store import Goals
from pipeline.routes.store import Routes
from pipeline.pictures import add_legend, add_scale_bar, label_colors, write_png

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
    img, box = _base(recon, goals, crop)
    colors = label_colors(np.arange(1, len(goals.goals) + 1)).reshape(-1, 3)
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
    for k, g in enumerate(goals.goals, 1):
        _marker(img, str(k), _px(grid, g.mass_center)[0])
    title = f"{goals.scene}: {len(goals.goals)} goals" + (
        f", {len(Routes(routes_path).episodes)} verified routes" if what == "routes" and routes_path else "")
    img = _finish(img, box, grid, title, crop)
    legend = [(tuple(int(v) for v in col), f"{k} {g.name} ({g.type})")
              for k, (g, col) in enumerate(zip(goals.goals, colors), 1)]
    extra = [((90, 90, 90), "other objects (outline)"), ((60, 60, 60), "- - landmark link")]
    if what == "routes":
        extra.append(((0, 0, 0), "route start + heading"))
    return write_png(Path(out_png), add_legend(img, legend + extra, title="goals"))


def render_episodes(recon_path, goals_path, runs: list[tuple[str, list, str]], out_pngs: list) -> list[Path]:
    """One picture per evaluated run ``(goal id, poses [[x, y, yaw], ...], '#rrggbb' colour)``: the goal filled,
    the walked path in the colour, its start (circle) and end (square). The base map is drawn once."""
    from pipeline.recon import Recon

    recon = Recon(recon_path)
    goals = Goals(goals_path)
    grid = recon.grid
    base, box = _base(recon, goals, True)
    written = []
    for (goal_id, poses, hex_colour), out_png in zip(runs, out_pngs):
        img = base.copy()
        col = tuple(int(hex_colour[i:i + 2], 16) for i in (1, 3, 5))
        goal = goals.goal(goal_id)
        for fp in goal.footprints:
            cv2.fillPoly(img, [_px(grid, fp)], (255, 215, 0))
            cv2.polylines(img, [_px(grid, fp)], True, (0, 0, 0), 2, cv2.LINE_AA)
        xy = np.asarray(poses, np.float64).reshape(-1, 3)[:, :2]
        pts = _px(grid, xy)
        cv2.polylines(img, [pts], False, col, 3, cv2.LINE_AA)
        s, e = (tuple(int(v) for v in pts[0]), tuple(int(v) for v in pts[-1]))
        cv2.circle(img, s, 6, col, -1, cv2.LINE_AA)
        cv2.circle(img, s, 6, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.rectangle(img, (e[0] - 5, e[1] - 5), (e[0] + 5, e[1] + 5), (0, 0, 0), -1)
        out = _finish(img, box, grid, f"{goal.name}: {len(xy) - 1} steps", True)
        out = add_legend(out, [((255, 215, 0), "goal"), (col, "path (circle = start)"), ((0, 0, 0), "end")])
        written.append(write_png(Path(out_png), out))
    return written


def _base(recon, goals: Goals, crop: bool) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """The lightened colour map upscaled ``SCALE`` times with every object outlined, and the crop box."""
    grid = recon.grid
    base = recon.color.copy()
    base[~(recon.occupancy > 0)] = 255
    img = cv2.resize(base, (grid.cols * SCALE, grid.rows * SCALE), interpolation=cv2.INTER_NEAREST)
    img = (img.astype(np.float32) * 0.75 + 255 * 0.25).astype(np.uint8)  # lighten so overlays read
    box = _crop_box(recon.occupancy > 0, img.shape) if crop else (0, img.shape[0], 0, img.shape[1])
    for o in goals.objects.values():
        cv2.polylines(img, [_px(grid, o.footprint)], True, (90, 90, 90), 1, cv2.LINE_AA)
    return img, box


def _finish(img: np.ndarray, box, grid: GridSpec, title: str, crop: bool) -> np.ndarray:
    """Crop, title band, scale bar and north arrow."""
    if crop:
        img = np.ascontiguousarray(img[box[0]:box[1], box[2]:box[3]])
    img = np.ascontiguousarray(np.pad(img, ((26, 0), (0, 0), (0, 0)), constant_values=255))
    img = add_scale_bar(img, grid.cell_size_m / SCALE)
    cv2.putText(img, title, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def _marker(img: np.ndarray, text: str, at: np.ndarray) -> None:
    """A numbered white disc at ``at`` (pixel u, v)."""
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.42, 1)
    r = max(w, h) // 2 + 4
    p = (int(at[0]), int(at[1]))
    cv2.circle(img, p, r, (255, 255, 255), -1, cv2.LINE_AA)
    cv2.circle(img, p, r, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, text, (p[0] - w // 2, p[1] + h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)


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
