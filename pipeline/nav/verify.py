"""Replay of stored routes: does executing the actions from p0 reach the goal without collision?

Independent of how the actions were made: an agent at (x, y, yaw) executes ``forward`` / ``left`` /
``right`` / ``stop`` on the navigable grid; a forward step collides when any point of the step
(sampled every third of a cell) lies in a non-navigable cell or off the grid (the agent then stays
put, as in Habitat). Success: no step collided and the final position is within ``success_m``
(1.5 m) of the goal's footprint polygon (0 inside it); given the goal ``region``
(:func:`pipeline.nav.region.goal_region`: within the success distance AND the mass centre in
line of sight on the reconstruction), the final cell must lie in it; given ``face_xy`` (the mass
centres) and ``hfov_deg``, one of them must lie inside the final view (|bearing| <= hfov / 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.geometry import GridSpec
from pipeline.nav.actions import FORWARD, LEFT, RIGHT, STOP
from pipeline.nav.fmm import one_segment_free


@dataclass(frozen=True)
class ReplayResult:
    final_xyyaw: tuple[float, float, float]
    collisions: int  # forward steps that were blocked
    first_collision: int  # index of the first blocked action, -1 if none
    travelled_m: float
    distance_to_goal_m: float
    success: bool
    in_region: bool = True  # final cell inside the goal region (True when no region was given)
    facing: bool = True  # a mass centre inside the final view (True when not checked)


def point_polygon_distance(xy: np.ndarray, polygon_xy: np.ndarray) -> float:
    """Distance (metres) from a point to a polygon; 0 inside or on it."""
    contour = np.asarray(polygon_xy, dtype=np.float32).reshape(-1, 1, 2)
    d = cv2.pointPolygonTest(contour, (float(xy[0]), float(xy[1])), True)
    return float(max(0.0, -d))


def replay(actions: np.ndarray, start_xyyaw, navigable: np.ndarray, grid: GridSpec, goal_polygons: list[np.ndarray],
           *, step_m: float = 0.25, turn_deg: float = 15.0, success_m: float = 1.5, region: np.ndarray | None = None,
           face_xy: np.ndarray | None = None, hfov_deg: float | None = None) -> ReplayResult:
    """Execute ``actions`` from ``start_xyyaw`` and judge the outcome against any of ``goal_polygons``
    (and the goal ``region`` ``(rows, cols)`` bool, and ``face_xy`` ``(K,2)`` within ``hfov_deg``)."""
    x, y, yaw = (float(v) for v in start_xyyaw)
    turn = np.deg2rad(turn_deg)
    nav = np.asarray(navigable, dtype=bool)
    start_rc = grid.world_to_cell(np.array([x, y]))
    collisions, first, travelled = 0, -1, 0.0
    if not (grid.inside(start_rc) and nav[start_rc[0], start_rc[1]]):
        collisions, first = 1, 0
    for i, a in enumerate(np.asarray(actions).tolist()):
        if a == STOP:
            break
        if a == LEFT:
            yaw += turn
        elif a == RIGHT:
            yaw -= turn
        elif a == FORWARD:
            nx, ny = x + step_m * np.cos(yaw), y + step_m * np.sin(yaw)
            if one_segment_free(nav, *_continuous_rc(grid, x, y), *_continuous_rc(grid, nx, ny)):
                x, y = nx, ny
                travelled += step_m
            else:
                collisions += 1
                first = i if first < 0 else first
        else:
            raise ValueError(f"unknown action code {a} at index {i}")
    dist = min((point_polygon_distance((x, y), p) for p in goal_polygons), default=float("inf"))
    in_region = facing = True
    if region is not None:
        rc = grid.world_to_cell(np.array([x, y]))
        in_region = bool(grid.inside(rc) and np.asarray(region, bool)[rc[0], rc[1]])
    if face_xy is not None and hfov_deg is not None:
        f = np.asarray(face_xy, np.float64).reshape(-1, 2)
        bearing = np.arctan2(f[:, 1] - y, f[:, 0] - x) - yaw
        bearing = np.abs(np.arctan2(np.sin(bearing), np.cos(bearing)))
        facing = bool((bearing <= np.deg2rad(hfov_deg) / 2 + 1e-9).any())
    return ReplayResult((x, y, float(np.arctan2(np.sin(yaw), np.cos(yaw)))), collisions, first, travelled, dist,
                        bool(collisions == 0 and dist <= success_m and in_region and facing), in_region, facing)


def _continuous_rc(grid: GridSpec, x: float, y: float) -> tuple[float, float]:
    """World point -> continuous (row, col) with cell centres at integers (rounding gives the cell)."""
    x0, y1 = grid.origin_xy
    return (y1 - float(y)) / grid.cell_size_m - 0.5, (float(x) - x0) / grid.cell_size_m - 0.5
