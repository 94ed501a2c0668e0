"""Path planning for the agents: pipeline.routes' FMM planner on the navigable grid, cropped and cached.

The scene's navigable cells usually cover a small part of the 600x600 grid, so the planner works
on the navigable bounding box (plus a margin) — a :class:`~pipeline.geometry.GridSpec` of its own
with the same cell size — which makes each fast-marching field several times cheaper. Fields are
cached per target key for the whole scene (targets repeat across episodes, seeds and settings), and so
are whole routes per start pose and target (:meth:`NavPlanner.route`).
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.routes.actions import Route, RoutePlanner, RouteSettings


class NavPlanner:
    """FMM routes on the cropped navigable grid; masks in and out are on the FULL grid."""

    def __init__(self, navigable: np.ndarray, grid: GridSpec, settings: RouteSettings, margin_cells: int = 4):
        nav = np.asarray(navigable, dtype=bool)
        self.grid, self.settings = grid, settings
        if nav.any():
            rr, cc = np.nonzero(nav)
            r0, r1 = max(int(rr.min()) - margin_cells, 0), min(int(rr.max()) + margin_cells + 1, grid.rows)
            c0, c1 = max(int(cc.min()) - margin_cells, 0), min(int(cc.max()) + margin_cells + 1, grid.cols)
        else:
            r0, r1, c0, c1 = 0, grid.rows, 0, grid.cols
        self.window = (slice(r0, r1), slice(c0, c1))
        s = grid.cell_size_m
        self.crop_grid = GridSpec(r1 - r0, c1 - c0, s, (grid.origin_xy[0] + c0 * s, grid.origin_xy[1] - r0 * s))
        self.planner = RoutePlanner(nav[self.window], self.crop_grid, settings)
        # route per (pose, target key, facing, end mask): deterministic agents repeat their first moves in every
        # feedback setting and seed, so the same route is asked for again and again. A target key names its
        # target (the FMM fields are cached by it too); an end mask is named by identity and kept alive here.
        self._routes: dict[tuple, tuple[Route | None, np.ndarray | None]] = {}

    def crop(self, mask: np.ndarray) -> np.ndarray:
        """A full-grid ``(rows, cols)`` mask cut to the planner's window (cells outside are dropped)."""
        return np.asarray(mask, dtype=bool)[self.window]

    def point_mask(self, xy) -> np.ndarray:
        """Full-grid mask of the cell of world point ``xy``."""
        m = np.zeros((self.grid.rows, self.grid.cols), bool)
        rc = self.grid.world_to_cell(np.asarray(xy, np.float64))
        if self.grid.inside(rc):
            m[rc[0], rc[1]] = True
        return m

    def route(self, pose, target_mask: np.ndarray, *, key, face_xy=None, end_mask: np.ndarray | None = None
              ) -> Route | None:
        """Route from ``pose`` (x, y, yaw) to within ``settings.stop_radius_m`` of ``target_mask`` (full grid);
        a walk that cannot finish in the target finishes inside ``end_mask`` (full grid) when given."""
        face = None if face_xy is None else np.asarray(face_xy, np.float64)
        memo = (tuple(float(v) for v in pose), key, None if face is None else (face.shape, face.tobytes()),
                None if end_mask is None else id(end_mask))
        hit = self._routes.get(memo)
        if hit is not None:
            return hit[0]
        sub = self.crop(target_mask)
        route = None
        if sub.any():
            end = None if end_mask is None else self.crop(end_mask)
            try:
                route = self.planner.route(pose, sub, key=key, face_xy=face, region=self.settings.stop_radius_m == 0,
                                           end_mask=end)
            except ValueError:  # descent stuck or action budget exceeded: treat as unreachable
                route = None
        self._routes[memo] = (route, end_mask)
        return route

    def geodesic(self, pose, target_mask: np.ndarray, *, key) -> float:
        """FMM distance (metres) from ``pose`` to the target region; inf when unreachable."""
        sub = self.crop(target_mask)
        if not sub.any():
            return float("inf")
        fld = self.planner.field(key, sub)
        rc = self.crop_grid.world_to_cell(np.asarray(pose[:2], np.float64))
        if not self.crop_grid.inside(rc):
            return float("inf")
        return float(fld[rc[0], rc[1]])
