"""Path planning for the agents: pipeline.routes' FMM planner on the navigable grid, cropped and cached.

The scene's navigable cells usually cover a small part of the 600x600 grid, so the planner works
on the navigable bounding box (plus a margin) — a :class:`~pipeline.geometry.GridSpec` of its own
with the same cell size — which makes each fast-marching field several times cheaper. Fields are
cached per target key for the whole scene (targets repeat across episodes, seeds and settings), and so
are whole routes per start pose and target (:meth:`NavPlanner.route`).

An agent's walk may end off the planner's clearance band (beside a wall, in a goal region that reaches it),
where no step on the agent's heading lattice follows the planned path ("no collision-free step"). An
agent's planner (``recover=True``) then gets back into the band first: the fewest turns and steps
(:data:`RECOVER_ACTIONS` at most) that reach a pose in the band from which the route exists, that route
appended. Without it, every target would be unreachable from such a pose for the rest of the episode.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.nav.actions import FORWARD, LEFT, RIGHT, Route, RoutePlanner, RouteSettings, route_parts
from pipeline.nav.fmm import GeodesicPath

RECOVER_ACTIONS = 16  # a stranded agent gets back into the clearance band in at most this many actions
RECOVER_TRIES = 8  # band poses (nearest first, in actions) a route is tried from


def points_round(navigable: np.ndarray, grid: GridSpec, xy, start, radius: float, n: int = 4) -> list[np.ndarray]:
    """Points round ``xy`` on its other sides than ``start``'s: ``n - 1`` bearings a ``1/n`` turn apart, going round
    from ``start``'s bearing, each the point ``radius`` from ``xy`` on that bearing, else half a step to either side
    of it, whose cell of the full-grid ``navigable`` mask is navigable (a bearing with none is left out)."""
    c = np.asarray(xy, np.float64)
    a0 = float(np.arctan2(*(np.asarray(start, np.float64)[:2] - c)[::-1]))
    out = []
    for k in range(1, n):
        for half in (0.0, 0.5, -0.5):
            a = a0 + 2 * np.pi * (k + half) / n
            p = c + radius * np.array([np.cos(a), np.sin(a)])
            if grid.holds(navigable, p):
                out.append(p)
                break
    return out


class NavPlanner:
    """FMM routes on the cropped navigable grid; masks in and out are on the FULL grid."""

    def __init__(self, navigable: np.ndarray, grid: GridSpec, settings: RouteSettings, margin_cells: int = 4,
                 *, recover: bool = False):
        nav = np.asarray(navigable, dtype=bool)
        self.grid, self.settings, self.recover = grid, settings, recover
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
            route = self._plan(pose, sub, key=key, face=face, end=end)
            if route is None and self.recover:
                route = self._recovered(pose, sub, key=key, face=face, end=end)
        self._routes[memo] = (route, end_mask)
        return route

    def route_into(self, pose, cells: np.ndarray, *, key, face_xy=None, end_mask: np.ndarray | None = None
                   ) -> Route | None:
        """:meth:`route` to the explicit ``cells`` (full grid) of a goal region; the planner's stop radius is 0."""
        if not self._region:
            raise ValueError("route_into needs a planner whose stop radius is 0 (targets are explicit cells)")
        return self.route(pose, cells, key=key, face_xy=face_xy, end_mask=end_mask)

    @property
    def _region(self) -> bool:
        """Targets are explicit cells (a zero stop radius), not points to stop near."""
        return self.settings.stop_radius_m == 0

    def _plan(self, pose, sub: np.ndarray, *, key, face, end) -> Route | None:
        """The planner's route on the cropped target ``sub``; None when unreachable (descent stuck or action budget
        exceeded)."""
        try:
            return self.planner.route(pose, sub, key=key, face_xy=face, region=self._region, end_mask=end)
        except ValueError:
            return None

    def _recovered(self, pose, sub: np.ndarray, *, key, face, end) -> Route | None:
        """The route from the nearest pose in the clearance band (fewest actions away) from which one exists,
        with the actions that get there first; None when the target is out of reach on the navigable mask or
        no band pose within :data:`RECOVER_ACTIONS` has a route."""
        rc = self.crop_grid.world_to_cell(np.asarray(pose[:2], np.float64))
        if not (self.crop_grid.inside(rc) and np.isfinite(self.planner.field(key, sub, "navigable",
                                                                             region=self._region)[rc[0], rc[1]])):
            return None
        for actions, xy in self._band_poses(pose)[:RECOVER_TRIES]:
            k = actions.count(LEFT) - actions.count(RIGHT)
            yaw = float(pose[2]) + k * np.deg2rad(self.settings.turn_deg)
            route = self._plan((xy[-1][0], xy[-1][1], yaw), sub, key=key, face=face, end=end)
            if route is None:
                continue
            s = self.settings
            walk = np.vstack([np.asarray(xy, np.float64), route.path.polyline_xy[1:]])
            path = GeodesicPath(walk, route.path.geodesic_m + s.step_m * actions.count(FORWARD),
                                GeodesicPath.polyline_length(walk))
            all_actions = np.concatenate([np.asarray(actions, np.uint8), route.actions])
            return Route(path, all_actions, route_parts(all_actions, step_m=s.step_m, turn_deg=s.turn_deg))
        return None

    def _band_poses(self, pose, inside=None) -> list[tuple[list[int], list[tuple[float, float]]]]:
        """Poses in the clearance band (or where ``inside(xy)`` holds) reachable from ``pose`` in at most
        :data:`RECOVER_ACTIONS` turns and collision-free steps, fewest actions first: ``(actions, positions walked
        through, start first)``; the positions are simulated exactly as the agent moves (headings
        ``yaw + k * turn_deg``)."""
        inside = inside or self._in_band
        turn = np.deg2rad(self.settings.turn_deg)
        n_headings = int(round(360.0 / self.settings.turn_deg))
        start = (float(pose[0]), float(pose[1]))
        seen = {(round(start[0], 4), round(start[1], 4), 0)}
        frontier: list[tuple[int, list[int], list[tuple[float, float]]]] = [(0, [], [start])]
        found = []
        for _ in range(RECOVER_ACTIONS):
            nxt = []
            for k, actions, xy in frontier:
                x, y = xy[-1]
                for a in (FORWARD, LEFT, RIGHT):
                    kk, pts = k, xy
                    if a == FORWARD:
                        yaw = float(pose[2]) + k * turn
                        q = (x + self.settings.step_m * np.cos(yaw), y + self.settings.step_m * np.sin(yaw))
                        if not self.planner.step_free(np.array([x, y]), np.array(q)):
                            continue
                        pts = xy + [q]
                    else:
                        kk = k + (1 if a == LEFT else -1)
                    state = (round(pts[-1][0], 4), round(pts[-1][1], 4), kk % n_headings)
                    if state in seen:
                        continue
                    seen.add(state)
                    if a == FORWARD and inside(pts[-1]):
                        found.append((actions + [a], pts))
                    else:
                        nxt.append((kk, actions + [a], pts))
            frontier = nxt
        return found

    def approach(self, pose, mask: np.ndarray) -> list[int] | None:
        """The fewest turns and collision-free forward steps (:data:`RECOVER_ACTIONS` at most) from ``pose`` to a
        position whose cell is in ``mask`` (full grid): a short last approach to a few cells a route's walk ended
        next to (a stair's end); [] when ``pose`` is in it already, None when none is that near."""
        crop = self.crop(mask)
        if self.planner.grid.holds(crop, np.asarray(pose[:2], np.float64)):
            return []
        found = self._band_poses(pose, inside=lambda xy: self.planner.grid.holds(crop, np.asarray(xy, np.float64)))
        return found[0][0] if found else None

    def _in_band(self, xy) -> bool:
        return self.planner.grid.holds(self.planner.plan_mask, xy)  # the routes planner's own cell test, on its band

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
