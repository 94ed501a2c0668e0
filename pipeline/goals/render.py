"""North-up pictures of goals and routes on the recon colour map (``zipon render <scene> --what goals|routes``).

``goals``: every object footprint outlined (grey), goal footprints filled in a colour per goal and
numbered at their mass centre (the legend below gives each number's personalized name and type, so
labels never collide or get clipped), landmark links (dashed) to the objects named in the landmark
feedback. ``routes``: the same goals, plus each stored episode's FMM polyline with its start pose (a
dot and a heading tick). :func:`render_episodes`: an evaluated episode's walked path over the same map.
A scale bar and north arrow come from :mod:`pipeline.pictures`.

A building is drawn one floor at a time (``floor``; ``zipon render --what goals`` writes ``goals_floor<k>.png``):
that floor's colour map, objects and goals (numbered as on every floor, the legend listing the floor's), each route's
leg on that floor (a cross-floor route is drawn on every floor it crosses), the stairs' ends (a triangle pointing up
at a foot, down at a head, named by the floor they lead to) and metre axes along the left and bottom edges. A
single-floor scene's picture is as it always was.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import ConfigError, InputDataError
from pipeline.geometry import GridSpec
from pipeline.goals.store import Goals
from pipeline.routes.store import Routes
from pipeline.pictures import add_legend, add_metre_axes, add_scale_bar, label_colors, write_png

WHATS = ("goals", "routes")
SCALE = 3  # output pixels per grid cell
STAIR_COLOUR = (255, 152, 0)  # the stairs' ends on a building's floor


def _px(grid: GridSpec, xy: np.ndarray) -> np.ndarray:
    """World (x, y) -> integer pixel (u, v) of the upscaled image (``shift``-free)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    x0, y1 = grid.origin_xy
    u = (xy[:, 0] - x0) / grid.cell_size_m * SCALE
    v = (y1 - xy[:, 1]) / grid.cell_size_m * SCALE
    return np.round(np.stack([u, v], -1)).astype(np.int32)


def render_goals(recon_path, goals_path, routes_path, what: str, out_png, *, crop: bool = True,
                 floor: int = 0) -> Path:
    """Draw goals (and routes) over the colour map of floor ``floor`` (0: the only floor of a single-floor scene);
    returns the PNG path."""
    from pipeline.recon import Recon

    if what not in WHATS:
        raise ConfigError(f"render --what {what!r}: expected one of {list(WHATS)}")
    recon = Recon(recon_path)
    n_floors = len(recon.floors)
    if not 0 <= floor < n_floors:
        raise ConfigError(f"--floor {floor}: {Path(recon_path).parent.name} has {n_floors} "
                          f"floor{'s' if n_floors != 1 else ''} (0..{n_floors - 1})")
    building = n_floors > 1
    goals = Goals(goals_path)
    level = recon.floor(floor)
    grid = level.grid
    img, box = _base(level, goals, crop, floor)
    colors = label_colors(np.arange(1, len(goals.goals) + 1)).reshape(-1, 3)
    shown = [(k, g, col) for k, (g, col) in enumerate(zip(goals.goals, colors), 1) if g.floor == floor]
    overlay = img.copy()
    for _, g, col in shown:
        for fp in g.footprints:
            cv2.fillPoly(overlay, [_px(grid, fp)], tuple(int(c) for c in col))
    img = cv2.addWeighted(overlay, 0.6, img, 0.4, 0)
    episodes = []
    if what == "routes" and routes_path is not None:
        routes = Routes(routes_path)
        episodes = [e for e in routes.episodes if floor in e.floors]
        gcol = {g.id: tuple(int(c) for c in col) for g, col in zip(goals.goals, colors)}
        for e in episodes:
            col = gcol.get(e.goal_id, (0, 0, 0))
            for f, xy in (e.legs() if building else [(floor, e.path_xy)]):
                if f == floor and len(xy):
                    cv2.polylines(img, [_px(grid, xy)], False, col, 2, cv2.LINE_AA)
            if e.start_floor != floor:
                continue
            s = _px(grid, e.start[:2])[0]
            tip = _px(grid, np.array(e.start[:2]) + 0.4 * np.array([np.cos(e.start[2]), np.sin(e.start[2])]))[0]
            cv2.circle(img, tuple(int(v) for v in s), 5, col, -1, cv2.LINE_AA)
            cv2.circle(img, tuple(int(v) for v in s), 5, (0, 0, 0), 1, cv2.LINE_AA)
            cv2.line(img, tuple(int(v) for v in s), tuple(int(v) for v in tip), (0, 0, 0), 2, cv2.LINE_AA)
    for _, g, col in shown:
        c = _px(grid, g.mass_center)[0]
        for lm in g.landmarks:
            o = goals.objects.get(lm["object"])
            if o is not None:
                _dashed(img, c, _px(grid, o.mass_center)[0], (60, 60, 60))
        for fp in g.footprints:
            cv2.polylines(img, [_px(grid, fp)], True, (0, 0, 0), 2, cv2.LINE_AA)
    if building:
        _stairs(img, recon, floor, grid)
    for k, g, _ in shown:
        _marker(img, str(k), _px(grid, g.mass_center)[0])
    if not building:
        title = f"{goals.scene}: {len(goals.goals)} goals" + (
            f", {len(episodes)} verified routes" if what == "routes" and routes_path else "")
    else:
        # short enough for a small floor's picture: goals shown of all, routes with a leg on this floor
        title = (f"{goals.scene}, {level.floor.name} ({level.floor_z:.2f} m): {len(shown)}/{len(goals.goals)} goals"
                 + (f", {len(episodes)} verified routes" if what == "routes" and routes_path else ""))
    img = _finish(img, box, grid, title, crop, axes=building)
    legend = [(tuple(int(v) for v in col), f"{k} {g.name} ({g.type})") for k, g, col in shown]
    extra = [((90, 90, 90), "other objects (outline)"), ((60, 60, 60), "- - landmark link")]
    if what == "routes":
        extra.append(((0, 0, 0), "route start + heading"))
    if building and recon.stairs:
        extra.append((STAIR_COLOUR, "stairs: up at a foot, down at a head"))
    return write_png(Path(out_png), add_legend(img, legend + extra, title="goals"))


def render_episodes(recon_path, goals_path, runs: list[tuple], out_pngs: list) -> list[Path]:
    """One picture per evaluated run ``(goal id, poses [[x, y, yaw], ...], '#rrggbb' colour[, floors])``: the goal
    filled, the walked path in the colour, its start (circle) and end (square). The base maps are drawn once.

    In a building, ``floors`` (the episode log's ``floors``: the floor of each pose) splits the path by floor: the
    picture has one panel per floor the run stood on (and the goal's floor), side by side in the order first
    reached, each that floor's map with metre axes, its stairs, the path's stretches on it and the goal where it is.
    """
    from pipeline.recon import Recon

    recon = Recon(recon_path)
    goals = Goals(goals_path)
    building = len(recon.floors) > 1
    bases: dict[int, tuple] = {}
    written = []
    for run, out_png in zip(runs, out_pngs):
        goal_id, poses, hex_colour = run[:3]
        col = tuple(int(hex_colour[i:i + 2], 16) for i in (1, 3, 5))
        goal = goals.goal(goal_id)
        xy = np.asarray(poses, np.float64).reshape(-1, 3)[:, :2]
        on = np.zeros(len(xy), int) if not building or len(run) < 4 or run[3] is None else np.asarray(run[3], int)
        if len(on) != len(xy) or on.min() < 0 or on.max() >= len(recon.floors):
            raise InputDataError(f"episode of goal {goal_id}: {len(on)} floors (ids {sorted(set(on.tolist()))}) for "
                                 f"{len(xy)} poses", field="log.floors",
                                 expected=f"one floor id of 0..{len(recon.floors) - 1} per pose")
        shown = list(dict.fromkeys([int(f) for f in on] + [goal.floor if building else 0]))
        panels = []
        for f in shown:
            level = recon.floor(f)
            if f not in bases:
                bases[f] = _base(level, goals, True, f)
            img, box = bases[f][0].copy(), bases[f][1]
            grid = level.grid
            if not building or goal.floor == f:
                for fp in goal.footprints:
                    cv2.fillPoly(img, [_px(grid, fp)], (255, 215, 0))
                    cv2.polylines(img, [_px(grid, fp)], True, (0, 0, 0), 2, cv2.LINE_AA)
            if building:
                _stairs(img, recon, f, grid)
            for stretch in _stretches(on == f):
                cv2.polylines(img, [_px(grid, xy[stretch])], False, col, 3, cv2.LINE_AA)
            pts = _px(grid, xy)
            if on[0] == f:
                s = tuple(int(v) for v in pts[0])
                cv2.circle(img, s, 6, col, -1, cv2.LINE_AA)
                cv2.circle(img, s, 6, (0, 0, 0), 1, cv2.LINE_AA)
            if on[-1] == f:
                e = tuple(int(v) for v in pts[-1])
                cv2.rectangle(img, (e[0] - 5, e[1] - 5), (e[0] + 5, e[1] + 5), (0, 0, 0), -1)
            title = f"{goal.name}: {len(xy) - 1} steps"
            if building:
                title = f"{level.floor.name} ({level.floor_z:.2f} m)" + (f" - {title}" if f == shown[0] else "")
            panels.append(_finish(img, box, grid, title, True, axes=building))
        out = _side_by_side(panels)
        legend = [((255, 215, 0), "goal"), (col, "path (circle = start)"), ((0, 0, 0), "end")]
        if building and recon.stairs:
            legend.append((STAIR_COLOUR, "stairs: up at a foot, down at a head"))
        written.append(write_png(Path(out_png), add_legend(out, legend)))
    return written


def _stretches(mask: np.ndarray) -> list[slice]:
    """The runs of consecutive True in ``mask`` as slices (a path's stretches on one floor)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _side_by_side(panels: list[np.ndarray], gap: int = 12) -> np.ndarray:
    """Panels left to right on white, top-aligned, ``gap`` pixels apart."""
    if len(panels) == 1:
        return panels[0]
    h = max(p.shape[0] for p in panels)
    cols = []
    for k, p in enumerate(panels):
        cols.append(np.pad(p, ((0, h - p.shape[0]), (0 if k == 0 else gap, 0), (0, 0)), constant_values=255))
    return np.ascontiguousarray(np.concatenate(cols, axis=1))


def _base(recon, goals: Goals, crop: bool, floor: int = 0) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """The lightened colour map (of ``recon``: a store, or one floor's grids) upscaled ``SCALE`` times with every
    object of floor ``floor`` outlined, and the crop box."""
    grid = recon.grid
    base = recon.color.copy()
    base[~(recon.occupancy > 0)] = 255
    img = cv2.resize(base, (grid.cols * SCALE, grid.rows * SCALE), interpolation=cv2.INTER_NEAREST)
    img = (img.astype(np.float32) * 0.75 + 255 * 0.25).astype(np.uint8)  # lighten so overlays read
    box = _crop_box(recon.occupancy > 0, img.shape) if crop else (0, img.shape[0], 0, img.shape[1])
    for o in goals.objects.values():
        if o.floor == floor:
            cv2.polylines(img, [_px(grid, o.footprint)], True, (90, 90, 90), 1, cv2.LINE_AA)
    return img, box


def _stairs(img: np.ndarray, recon, floor: int, grid: GridSpec) -> None:
    """The ends of the stairs on ``floor``: a triangle pointing up at a foot, down at a head, and where it leads."""
    for link in recon.stairs:
        for end, up, other in ((link.bottom, True, link.top.floor), (link.top, False, link.bottom.floor)):
            if end.floor != floor:
                continue
            u, v = (int(a) for a in _px(grid, end.xy)[0])
            d = -1 if up else 1
            tri = np.array([[u, v + 11 * d], [u - 10, v - 8 * d], [u + 10, v - 8 * d]], np.int32)
            cv2.fillPoly(img, [tri], STAIR_COLOUR, cv2.LINE_AA)
            cv2.polylines(img, [tri], True, (0, 0, 0), 1, cv2.LINE_AA)
            text = f"{link.kind} {'up' if up else 'down'} to floor {other}"
            for colour, width in (((255, 255, 255), 3), ((0, 0, 0), 1)):
                cv2.putText(img, text, (u + 13, v + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.42, colour, width, cv2.LINE_AA)


def _finish(img: np.ndarray, box, grid: GridSpec, title: str, crop: bool, *, axes: bool = False) -> np.ndarray:
    """Crop, title band, scale bar and north arrow; ``axes``: metre ticks along the left and bottom edges."""
    if not crop:
        box = (0, img.shape[0], 0, img.shape[1])
    img = np.ascontiguousarray(img[box[0]:box[1], box[2]:box[3]])
    if axes:  # the scale bar and north arrow on the map itself, the ticks in margins around it
        px_per_m = SCALE / grid.cell_size_m
        img = add_metre_axes(add_scale_bar(img, grid.cell_size_m / SCALE), grid.origin_xy[0] + box[2] / px_per_m,
                             grid.origin_xy[1] - box[0] / px_per_m, px_per_m)
    img = np.ascontiguousarray(np.pad(img, ((26, 0), (0, 0), (0, 0)), constant_values=255))
    if not axes:
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
