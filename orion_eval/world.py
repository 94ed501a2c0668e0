"""The evaluation world: the agent's body on the navigable grid, its actions, and the success rule.

Actions (the paper's): ``TurnLeft`` / ``TurnRight`` by ``turn_deg`` (15 deg; left = counter-clockwise),
``MoveForward`` by ``step_m`` (0.25 m) — both as routes.zarr records them — and ``Talk`` (counted by the episode, see
:mod:`orion_eval.episode`). A forward step collides when any point of it (sampled every third of a
cell) leaves the navigable cells; the agent then stays put, as in Habitat and in
:func:`pipeline.nav.verify.replay`.

A building (several floors) is one navigable grid per floor joined by its stairs (:class:`Stairway`). The body
stands on a floor (:attr:`Body.floor`; :class:`Pose` carries it beside x, y, yaw). It climbs as a Habitat agent does,
with ``MoveForward`` on the stair's surface: a forward step from a stair's end on its floor (the cells the building
planner leads a route to: :meth:`pipeline.nav.building.BuildingPlanner.stair_end_cells`), facing along the stair
(within half a turn step), steps onto it; each further forward step along it (up or down) walks one of its
``ceil(run / step_m)`` steps, the last onto the far end's floor, and adds the stair's length along its slope over
those steps to the distance travelled. A turn on a stair turns; a step across it collides.

Success (``eval.success_rule``):

- ``paper``: the agent is within routes.zarr's ``success_m`` (1.5 m) of the goal's footprint (0 inside),
  the goal's mass centre lies inside the ``hfov_deg`` (90 deg) ego view, and it is in line of sight;
- ``navchat``: navchat's tighter bands on (distance, |bearing|): (0.6 m, 45 deg), (1.2 m, 30 deg),
  (1.4 m, 15 deg — standing in for "enough goal pixels near the image centre"), plus line of sight.

Line of sight: the routes module's one definition (:class:`pipeline.nav.region.MeshSight`,
the same test that defines the goal region the routes and the human agent aim for): rays from the
camera (above the agent) to the goal's mass-centre column, at half and the top of the object, cast
against the RECONSTRUCTED mesh; in sight when one ray reaches the target or first hits the goal's
own footprint (dilated two cells). Without a mesh, a 2.5-D test on the height grid stands in (a
cell blocks when its top is above the segment there).
Any member of a same_goal group counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.nav.actions import FORWARD, LEFT, RIGHT, STOP, wrap_angle
from pipeline.nav.fmm import segment_free
from pipeline.nav.region import SIGHT_LEVELS, own_cells, sight_levels
from pipeline.nav.verify import point_polygon_distance

if TYPE_CHECKING:
    from pipeline.nav.building import StairLink

ACTION_WORDS = {FORWARD: "MoveForward", LEFT: "TurnLeft", RIGHT: "TurnRight", STOP: "Stop"}
NAVCHAT_BANDS = ((0.6, 45.0), (1.2, 30.0), (1.4, 15.0))


class Pose(tuple):
    """``(x, y, yaw)`` world metres and radians, and :attr:`floor`, the floor it stands on (0 on a single floor):
    what every module and the user are given, read as the plain triple it was before buildings."""

    floor: int

    def __new__(cls, xyyaw, floor: int = 0):
        self = super().__new__(cls, tuple(xyyaw))
        self.floor = int(floor)
        return self


def floor_of(pose) -> int:
    """The floor a pose stands on (0 for a plain ``(x, y, yaw)``)."""
    return int(getattr(pose, "floor", 0))


@dataclass
class Body:
    """The agent's pose on the grid and what it has done (world metres, radians). In a building, ``floor`` is the
    floor it stands on (or climbs from) and ``stair`` ``(stair index, step from its foot)`` while on a stair."""

    x: float
    y: float
    yaw: float
    travelled_m: float = 0.0
    steps: int = 0
    collisions: int = 0
    actions: list[int] = field(default_factory=list)
    poses: list[tuple[float, float, float]] = field(default_factory=list)
    floor: int = 0
    stair: tuple[int, int] | None = None
    floors: list[int] = field(default_factory=list)  # the floor of each of ``poses``

    @property
    def pose(self) -> Pose:
        return Pose((self.x, self.y, self.yaw), self.floor)


@dataclass(frozen=True)
class Stairway:
    """A stair of a building as the world walks it: its ``link`` (foot on the lower floor, head on the upper), the
    full-grid ``(rows, cols)`` bool cells ``ends[floor]`` from which it is stepped onto, and that grid."""

    link: StairLink
    ends: dict[int, np.ndarray]
    grid: GridSpec
    step_m: float

    @property
    def steps(self) -> int:
        """Forward steps that walk it (its horizontal run in steps, as the building planner's climb counts them)."""
        return max(1, int(math.ceil(self.link.run_m / self.step_m - 1e-9)))

    @property
    def up_heading(self) -> float:
        (x0, y0), (x1, y1) = self.link.foot_xy, self.link.head_xy
        return math.atan2(y1 - y0, x1 - x0)

    def at_end(self, floor: int, x: float, y: float) -> bool:
        """Whether ``(x, y)`` on ``floor`` is on the cells the stair is stepped onto from."""
        mask = self.ends.get(floor)
        if mask is None:
            return False
        return self.grid.holds(mask, (x, y))


class World:
    """Moves a :class:`Body` on ``navigable`` ``(rows, cols)`` bool of ``grid`` (floor 0); a building adds its other
    floors ``floors`` ``{floor: (navigable, grid)}`` and its ``stairs`` (see the module docstring)."""

    def __init__(self, navigable: np.ndarray, grid: GridSpec, *, step_m: float = 0.25, turn_deg: float = 15.0,
                 floors: dict[int, tuple[np.ndarray, GridSpec]] | None = None, stairs: list[Stairway] = ()):
        self.nav = np.asarray(navigable, dtype=bool)
        self.grid, self.step_m, self.turn = grid, float(step_m), math.radians(turn_deg)
        self.levels = {0: (self.nav, grid), **{f: (np.asarray(n, bool), g) for f, (n, g) in (floors or {}).items()}}
        self.stairs = list(stairs)

    @staticmethod
    def _crc(grid: GridSpec, x: float, y: float) -> np.ndarray:
        x0, y1 = grid.origin_xy
        return np.array([(y1 - y) / grid.cell_size_m - 0.5, (x - x0) / grid.cell_size_m - 0.5])

    def _facing(self, yaw: float, heading: float) -> bool:
        return abs(float(wrap_angle(yaw - heading))) <= self.turn / 2 + 1e-6

    def _stair_ahead(self, body: Body) -> int | None:
        """The stair a forward step from ``body`` steps onto (its index), or None."""
        for i, way in enumerate(self.stairs):
            lk = way.link
            if body.floor not in (lk.lower, lk.upper) or not way.at_end(body.floor, body.x, body.y):
                continue
            into = way.up_heading if body.floor == lk.lower else way.up_heading + math.pi
            if self._facing(body.yaw, into):
                return i
        return None

    def _climb(self, body: Body, i: int) -> bool:
        """One forward step on stair ``i`` (stepping onto it from its end when the body is not on it yet)."""
        way = self.stairs[i]
        lk, n = way.link, way.steps
        at = body.stair[1] if body.stair is not None else (0 if body.floor == lk.lower else n)
        if self._facing(body.yaw, way.up_heading):
            at += 1
        elif self._facing(body.yaw, way.up_heading + math.pi):
            at -= 1
        else:
            return False  # across the stair: its sides
        body.travelled_m += lk.length_m / n
        if at >= n or at <= 0:
            body.floor = lk.upper if at >= n else lk.lower
            body.x, body.y = (float(v) for v in (lk.head_xy if at >= n else lk.foot_xy))
            body.stair = None
        else:
            (x0, y0), (x1, y1) = lk.foot_xy, lk.head_xy
            body.x, body.y = x0 + (x1 - x0) * at / n, y0 + (y1 - y0) * at / n
            body.stair = (i, at)
        return True

    def act(self, body: Body, action: int) -> bool:
        """Execute one action code; returns False when a forward step collided."""
        ok = True
        if action == LEFT:
            body.yaw = float(wrap_angle(body.yaw + self.turn))
        elif action == RIGHT:
            body.yaw = float(wrap_angle(body.yaw - self.turn))
        elif action == FORWARD:
            stair = None
            if self.stairs:
                stair = body.stair[0] if body.stair is not None else self._stair_ahead(body)
            if stair is not None:
                ok = self._climb(body, stair)
            else:
                nav, grid = self.levels[body.floor]
                nx, ny = body.x + self.step_m * math.cos(body.yaw), body.y + self.step_m * math.sin(body.yaw)
                if segment_free(nav, self._crc(grid, body.x, body.y), self._crc(grid, nx, ny))[0]:
                    body.x, body.y = nx, ny
                    body.travelled_m += self.step_m
                else:
                    ok = False
            if not ok:
                body.collisions += 1
        elif action != STOP:
            raise ValueError(f"unknown action code {action}")
        if action != STOP:
            body.steps += 1
            body.actions.append(int(action))
            body.poses.append((round(body.x, 4), round(body.y, 4), round(body.yaw, 4)))
            body.floors.append(body.floor)
        return ok


@dataclass(frozen=True)
class GoalGeometry:
    """What the success rule needs of one goal: per member footprint, mass centre and height band."""

    footprints: tuple[np.ndarray, ...]  # (N,2) world polygons
    mass_centers: np.ndarray  # (K,2)
    z_levels: np.ndarray  # (K,L) heights above the floor where the mass centre column is sighted
    own_cells: np.ndarray  # (rows, cols) bool: the group's footprint cells, dilated by one cell


class SuccessRule:
    """The paper's (or navchat's) success test on one scene; see the module docstring."""

    def __init__(self, grid: GridSpec, height: np.ndarray, camera_height_m: float, *, rule: str = "paper",
                 distance_m: float = 1.5, hfov_deg: float = 90.0, sight=None):
        self.grid, self.rule, self.distance_m = grid, rule, float(distance_m)
        self.half_fov = math.radians(hfov_deg) / 2.0
        self.height = np.nan_to_num(np.asarray(height, dtype=np.float32), nan=-np.inf)
        self.camera_h = float(camera_height_m)
        self.sight = sight  # (origins (N,2), target_xy, z_levels, own) -> (N,) bool; None = 2.5-D height grid
        # verdicts per (pose, goal): the user judges the same poses in every feedback setting (agents are
        # deterministic); a goal geometry is named by identity and kept alive with its verdicts
        self._verdicts: dict[tuple, tuple[dict, GoalGeometry]] = {}

    def geometry(self, footprints, mass_centers, z_ranges, footprint_mask: np.ndarray) -> GoalGeometry:
        own = own_cells(footprint_mask)
        z_levels = np.array([sight_levels(z) for z in np.asarray(z_ranges, float)]).reshape(-1, len(SIGHT_LEVELS))
        return GoalGeometry(tuple(np.asarray(f, np.float64) for f in footprints),
                            np.asarray(mass_centers, np.float64).reshape(-1, 2), z_levels, own)

    def line_of_sight(self, xy, target_xy, z_levels, own: np.ndarray) -> bool:
        """Whether the goal's mass centre column (at ``z_levels`` above the floor) is in sight from ``xy``."""
        if self.sight is not None:
            return bool(self.sight(np.asarray(xy)[None], target_xy, z_levels, own)[0])
        a, b = np.asarray(xy, np.float64), np.asarray(target_xy, np.float64)
        length = float(np.linalg.norm(b - a))
        n = max(2, int(math.ceil(length / (self.grid.cell_size_m / 2))) + 1)
        t = np.linspace(0.0, 1.0, n)[1:-1]
        pts = a[None] + (b - a)[None] * t[:, None]
        rc = self.grid.world_to_cell(pts)
        inside = self.grid.inside(rc)
        for target_z in z_levels:
            z = (self.camera_h + (target_z - self.camera_h) * t)[inside]
            r = rc[inside]
            blocked = (self.height[r[:, 0], r[:, 1]] > z + 0.05) & ~own[r[:, 0], r[:, 1]]
            if not blocked.any():
                return True
        return False

    def evaluate(self, pose, goal: GoalGeometry) -> dict:
        """``{success, distance_m, bearing_deg, visible}`` for the best member of the goal's group."""
        x, y, yaw = (float(v) for v in pose)
        memo = (x, y, yaw, id(goal))
        if memo not in self._verdicts:
            self._verdicts[memo] = (self._evaluate(x, y, yaw, goal), goal)
        return dict(self._verdicts[memo][0])

    def _evaluate(self, x: float, y: float, yaw: float, goal: GoalGeometry) -> dict:
        best = {"success": False, "distance_m": math.inf, "bearing_deg": 180.0, "visible": False}
        for k, poly in enumerate(goal.footprints):
            d = point_polygon_distance((x, y), poly)
            mc = goal.mass_centers[k]
            bearing = float(wrap_angle(math.atan2(mc[1] - y, mc[0] - x) - yaw))
            if d > max(self.distance_m, NAVCHAT_BANDS[-1][0]) + 1e-9:
                ok = vis = False
            else:
                vis = self.line_of_sight((x, y), mc, goal.z_levels[k], goal.own_cells)
                if self.rule == "paper":
                    ok = d <= self.distance_m and abs(bearing) <= self.half_fov and vis
                else:
                    ok = vis and any(d <= dm and abs(bearing) <= math.radians(ad) for dm, ad in NAVCHAT_BANDS)
            cand = {"success": bool(ok), "distance_m": round(d, 4), "bearing_deg": round(math.degrees(bearing), 2),
                    "visible": bool(vis)}
            if (cand["success"], -cand["distance_m"]) > (best["success"], -best["distance_m"]):
                best = cand
        return best
