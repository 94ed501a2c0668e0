"""Routes across the floors of a building: each floor's navigable grid planned by fast marching, the floors joined
at their stairs.

A building is its floors' :class:`~pipeline.nav.actions.RoutePlanner` (one grid each, all on the same world xy) and
its :class:`StairLink` s: a staircase or ramp walked straight from its foot on the lower floor to its head on the upper
one. A stair's cells are not on either floor's navigable grid (they climb between the two); a route reaches the foot
(or head), turns to face along the stair and walks it with forward steps, as a Habitat agent climbs: MoveForward on the
stair's surface. Distances across floors are the floors' geodesic distances to and from the stair ends plus the
stair's own length along its slope (the 3D walk, as Habitat measures a geodesic across floors).

:class:`BuildingPlanner` finds the cheapest sequence of stairs by Dijkstra over the stair ends (the fast-marching
field of each stair end, cached per floor), then plans each floor's leg with the floor's own planner, the last leg
into the goal region with :func:`pipeline.nav.region.route_to_goal`. A floor that no stair joins to the others is
reported by :meth:`BuildingPlanner.unlinked`; its goals are reachable only from starts on it, and a start elsewhere
gets ``None`` (never an infinite distance taken for a number).

Procedural text says the stairs the way a person does: ``"turn left, go forward 3 meters; go up the stairs; at the
top turn right, go forward 4 meters"``.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.nav.actions import FORWARD, LEFT, RIGHT, Route, RoutePlanner, route_text, wrap_angle
from pipeline.nav.region import GoalTargets, route_to_goal

STAIR_END_RADIUS_M = 0.3  # a leg to a stair ends within this distance of the stair's foot or head


@dataclass(frozen=True)
class StairLink:
    """A staircase (or ramp) joining floor ``lower`` to floor ``upper``: walked straight from ``foot_xy`` (on the
    lower floor's grid) to ``head_xy`` (on the upper floor's grid), world metres; ``rise_m`` the height it climbs."""

    id: str
    lower: int
    upper: int
    foot_xy: tuple[float, float]
    head_xy: tuple[float, float]
    rise_m: float

    @property
    def run_m(self) -> float:
        """Horizontal length, metres."""
        return float(math.dist(self.foot_xy, self.head_xy))

    @property
    def length_m(self) -> float:
        """Length along the slope, metres: what walking it adds to a route."""
        return float(math.hypot(self.run_m, self.rise_m))

    def end_on(self, floor: int) -> tuple[float, float]:
        """The stair's end on ``floor`` (its foot on the lower floor, its head on the upper one)."""
        if floor not in (self.lower, self.upper):
            raise ValueError(f"stair {self.id} joins floors {self.lower} and {self.upper}, not {floor}")
        return self.foot_xy if floor == self.lower else self.head_xy

    def other(self, floor: int) -> int:
        return self.upper if floor == self.lower else self.lower


@dataclass
class Climb:
    """One stair walked in a route: ``up`` or down, with the actions that walk it."""

    link: StairLink
    up: bool
    actions: np.ndarray  # (A,) uint8: the turns to face along the stair, then forward steps

    @property
    def text(self) -> str:
        return "go up the stairs" if self.up else "go down the stairs"


@dataclass
class FloorRoute:
    """A route that may cross floors: ``legs`` [(floor, Route or None when the leg is empty)] joined by ``climbs``
    (one fewer than the legs). ``actions`` are the whole walk in order; ``length_m`` the walked length."""

    legs: list[tuple[int, Route | None]]
    climbs: list[Climb] = field(default_factory=list)

    @property
    def floors(self) -> list[int]:
        return [f for f, _ in self.legs]

    @property
    def actions(self) -> np.ndarray:
        out: list[np.ndarray] = []
        for i, (_, route) in enumerate(self.legs):
            if route is not None:
                acts = np.asarray(route.actions, np.uint8)
                out.append(acts[acts != 0])  # a leg's stop ends only the last leg
            if i < len(self.climbs):
                out.append(self.climbs[i].actions)
        out.append(np.zeros(1, np.uint8))
        return np.concatenate(out).astype(np.uint8)

    @property
    def segments(self) -> list[int]:
        """Actions per piece of :attr:`actions`, in order: leg, climb, leg, ..., the last leg with the stop."""
        out = []
        for i, (_, route) in enumerate(self.legs):
            out.append(0 if route is None else int(np.count_nonzero(route.actions)))
            if i < len(self.climbs):
                out.append(len(self.climbs[i].actions))
        out[-1] += 1
        return out

    @property
    def length_m(self) -> float:
        legs = sum(float(r.path.length_m) for _, r in self.legs if r is not None)
        return legs + sum(c.link.length_m for c in self.climbs)

    @property
    def parts(self) -> list:
        return [p for _, r in self.legs if r is not None for p in r.parts]

    @property
    def text(self) -> str:
        """The legs' route text with the stairs between them: ``"...; go up the stairs; at the top ..."``."""
        pieces: list[str] = []
        for i, (_, route) in enumerate(self.legs):
            leg = route_text(route.parts) if route is not None else ""
            if i > 0 and leg:
                leg = ("at the top " if self.climbs[i - 1].up else "at the bottom ") + leg
            if leg:
                pieces.append(leg)
            if i < len(self.climbs):
                pieces.append(self.climbs[i].text)
        return "; ".join(pieces)


class BuildingPlanner:
    """Routes over the floors ``planners`` ``{floor id: RoutePlanner}`` joined by ``links``."""

    def __init__(self, planners: dict[int, RoutePlanner], links: list[StairLink]):
        self.planners = dict(planners)
        self.links = [lk for lk in links if lk.lower in self.planners and lk.upper in self.planners]
        self._end_masks: dict[tuple[str, int], np.ndarray | None] = {}

    # ------------------------------------------------------------------ the floors' graph
    def unlinked(self) -> list[int]:
        """Floors no usable stair joins to another floor (only in a building of two floors or more)."""
        if len(self.planners) < 2:
            return []
        joined = {f for lk in self.links for f in (lk.lower, lk.upper)
                  if self.stair_end_cells(lk, lk.lower) is not None and self.stair_end_cells(lk, lk.upper) is not None}
        return sorted(set(self.planners) - joined)

    def stair_end_cells(self, link: StairLink, floor: int) -> np.ndarray | None:
        """``(rows, cols)`` bool: the navigable cells of ``floor`` within :data:`STAIR_END_RADIUS_M` of the stair's
        end there; None when there is none (the stair does not reach that floor's walkable space). All of them, the
        cells in the clearance band along a wall or the stairwell's edge included: a stair's end lies at such an edge,
        and a leg's walk (whole steps) often stops on one of them — where the climb starts as well."""
        key = (link.id, floor)
        if key not in self._end_masks:
            planner = self.planners[floor]
            g = planner.grid
            xy = np.asarray(link.end_on(floor), np.float64)
            rc = g.world_to_cell(xy)
            pad = int(math.ceil(STAIR_END_RADIUS_M / g.cell_size_m)) + 1
            mask = np.zeros(planner.navigable.shape, bool)
            r0, r1 = max(rc[0] - pad, 0), min(rc[0] + pad + 1, g.rows)
            c0, c1 = max(rc[1] - pad, 0), min(rc[1] + pad + 1, g.cols)
            if r0 < r1 and c0 < c1:
                rr, cc = np.mgrid[r0:r1, c0:c1]
                centres = g.cell_to_world(np.stack([rr.ravel(), cc.ravel()], axis=1))
                near = (np.hypot(*(centres - xy).T) <= STAIR_END_RADIUS_M).reshape(rr.shape)
                mask[r0:r1, c0:c1] = near & planner.navigable[r0:r1, c0:c1]
            self._end_masks[key] = mask if mask.any() else None
        return self._end_masks[key]

    def stair_end_field(self, link: StairLink, floor: int) -> np.ndarray | None:
        """Geodesic distance (metres, navigable mask) from every cell of ``floor`` to the stair's end there."""
        mask = self.stair_end_cells(link, floor)
        if mask is None:
            return None
        return self.planners[floor].field(("stair", link.id), mask, "navigable", region=True)

    def stair_sequence(self, floor: int, xy, goal_floor: int, goal_field: np.ndarray
                       ) -> tuple[float, list[tuple[StairLink, bool]]] | None:
        """The cheapest way from ``xy`` on ``floor`` to the goal on ``goal_floor``: ``(geodesic metres, [(stair,
        up)])``, ``goal_field`` the goal floor's distance field to the goal region; None when no stairs lead there."""
        start_rc = self.planners[floor].grid.world_to_cell(np.asarray(xy, np.float64))
        if not self.planners[floor].grid.inside(start_rc):
            return None

        def at(fld: np.ndarray | None, floor_: int, point) -> float:
            if fld is None:
                return math.inf
            rc = self.planners[floor_].grid.world_to_cell(np.asarray(point, np.float64))
            return float(fld[rc[0], rc[1]]) if self.planners[floor_].grid.inside(rc) else math.inf

        best = (math.inf, [])
        if floor == goal_floor:
            best = (at(goal_field, floor, xy), [])
        # Dijkstra over (stair, the floor it is entered from); the cost is the distance walked to its far end
        heap: list[tuple[float, int, str, int, list]] = []
        tick = 0
        for lk in self.links:
            if floor in (lk.lower, lk.upper):
                d = at(self.stair_end_field(lk, floor), floor, xy)
                if math.isfinite(d):
                    heap.append((d + lk.length_m, tick, lk.id, floor, [(lk, floor == lk.lower)]))
                    tick += 1
        heapq.heapify(heap)
        done: set[tuple[str, int]] = set()
        by_id = {lk.id: lk for lk in self.links}
        while heap:
            cost, _, lid, entered, seq = heapq.heappop(heap)
            if cost >= best[0] or (lid, entered) in done:
                continue
            done.add((lid, entered))
            lk = by_id[lid]
            arrived = lk.other(entered)
            end = lk.end_on(arrived)
            if arrived == goal_floor:
                total = cost + at(goal_field, arrived, end)
                if total < best[0]:
                    best = (total, seq)
            for nxt in self.links:
                if nxt.id == lid or arrived not in (nxt.lower, nxt.upper) or (nxt.id, arrived) in done:
                    continue
                d = at(self.stair_end_field(nxt, arrived), arrived, end)
                if math.isfinite(d):
                    tick += 1
                    heapq.heappush(heap, (cost + d + nxt.length_m, tick, nxt.id, arrived,
                                          seq + [(nxt, arrived == nxt.lower)]))
        return best if math.isfinite(best[0]) else None

    # ------------------------------------------------------------------ routes
    def route_to_goal(self, floor: int, pose, goal_floor: int, targets: GoalTargets, *, key, face_xy
                      ) -> FloorRoute | None:
        """The route from ``pose`` (x, y, yaw) on ``floor`` into the goal region ``targets`` on ``goal_floor``,
        over the stairs when they are on other floors; None when unreachable."""
        goal_planner = self.planners[goal_floor]
        if not targets.region.any():
            return None
        goal_field = goal_planner.field((key, "region"), targets.region, "navigable", region=True)
        found = self.stair_sequence(floor, pose[:2], goal_floor, goal_field)
        if found is None:
            return None
        _, seq = found
        legs: list[tuple[int, Route | None]] = []
        climbs: list[Climb] = []
        here, at_pose = floor, tuple(float(v) for v in pose)
        for lk, up in seq:
            far = lk.end_on(lk.other(here))
            near = lk.end_on(here)
            planner = self.planners[here]
            leg = planner.route_into(at_pose, self.stair_end_cells(lk, here), key=("stair", lk.id), face_xy=np.asarray(far))
            if leg is None:
                return None
            legs.append((here, leg))
            end_xy, end_yaw = _walk_end(planner, at_pose, leg)
            climbs.append(Climb(lk, up, _climb_actions(end_xy, end_yaw, near, far, planner.settings)))
            here = lk.other(here)
            at_pose = (float(far[0]), float(far[1]), float(math.atan2(far[1] - near[1], far[0] - near[0])))
        last = route_to_goal(goal_planner, at_pose, targets, key=key, face_xy=face_xy)
        if last is None and not seq:
            return None
        legs.append((here, last))
        return FloorRoute(legs, climbs)


def _walk_end(planner: RoutePlanner, pose, route: Route) -> tuple[np.ndarray, float]:
    """Where walking ``route`` from ``pose`` ends on the planner's grid: ``((2,) xy, yaw radians)``."""
    from pipeline.nav.verify import replay

    s = planner.settings
    res = replay(route.actions, pose, planner.navigable, planner.grid, [], step_m=s.step_m, turn_deg=s.turn_deg)
    x, y, yaw = res.final_xyyaw
    return np.array([x, y]), float(yaw)


def _climb_actions(xy: np.ndarray, yaw: float, near, far, settings) -> np.ndarray:
    """Turns to face from ``xy`` towards the stair's far end, then the forward steps that walk from the stair's
    ``near`` end to its ``far`` end (the steps taken on the stair's surface, counted along the horizontal run)."""
    heading = math.atan2(far[1] - near[1], far[0] - near[0])
    turn = math.radians(settings.turn_deg)
    k = int(round(float(wrap_angle(heading - yaw)) / turn))
    turns = [LEFT] * k if k > 0 else [RIGHT] * (-k)
    steps = int(math.ceil(math.dist(near, far) / settings.step_m - 1e-9))
    return np.array(turns + [FORWARD] * steps, np.uint8)


def building_planner(recon, settings) -> BuildingPlanner:
    """The :class:`BuildingPlanner` of a reconstruction (a :class:`pipeline.recon.store.Recon`): one planner per floor
    on that floor's navigable grid, joined at the stairs found in it (each stair's landing endpoints)."""
    planners = {}
    for f in range(len(recon.floors)):
        fg = recon.floor(f)
        planners[f] = RoutePlanner(fg.navigable, fg.grid, settings)
    links = [StairLink(f"stairs_{s.id}", s.bottom.floor, s.top.floor, tuple(s.bottom.xy), tuple(s.top.xy),
                       float(s.rise_m)) for s in recon.stairs]  # each landing's endpoint, world xy
    return BuildingPlanner(planners, links)
