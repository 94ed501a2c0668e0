"""Discrete actions along a path, and procedural ("turn left, go forward 5 meters") text.

The task's action space: ``forward`` (``step_m``, 0.25 m), ``left`` / ``right`` (``turn_deg``, 15 deg;
left = counter-clockwise, yaw grows), ``stop``. :func:`follow_polyline` turns a geodesic polyline
into actions; :func:`route_parts` cuts an action sequence the way navchat does (runs of 3+ equal
actions; turns of |a| >= 135 deg "turn around", >= 45 deg left, <= -45 deg right; forwards of 3+
steps; consecutive forwards merge. Going further than navchat, consecutive turns add up, and the
steps of a chunk with less than 45 deg of net turning count toward the neighbouring forwards);
:func:`route_text` says the parts in words. :class:`RoutePlanner` gives the instruction from any
pose (the evaluator's simulated user calls it mid-episode); :func:`procedural_allowed` is navchat's
rule for when the user sends it (goal in another room, at most 3 parts).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pipeline.config import TaskParams
from pipeline.geometry import GridSpec
from pipeline.nav.codes import ACTION_NAMES, FORWARD, LEFT, RIGHT, STOP  # noqa: F401 (re-exported)
from pipeline.nav.fmm import (GeodesicPath, geodesic_field, joined_parts, mask_parts, one_segment_free, planning_mask,
                              shortest_path, target_region)

DEEP_CELLS = 2  # a walk finishes this many cells inside its aim when a few more steps get it there
ENTRY_CELLS = 10  # a pose off its goal's field joins it at a finite cell at most this many cells away (per axis)
_LETTER = {FORWARD: "f", LEFT: "l", RIGHT: "r"}


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped to ``(-pi, pi]``."""
    return -((-np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)


def follow_polyline(polyline_xy: np.ndarray, start_yaw: float, *, step_m: float = 0.25, turn_deg: float = 15.0,
                    face_xy: np.ndarray | None = None, band_m: float = 0.08, max_actions: int = 2000,
                    free=None, goal=None, max_extra_steps: int = 2) -> np.ndarray:
    """Actions ``(A,)`` uint8 that drive a (x, y, yaw) agent from ``polyline_xy[0]`` along the polyline.

    Headings are limited to ``start_yaw + k * turn_deg``. Each segment is tracked with the two lattice
    headings that bracket its direction: the agent walks straight and switches to the other bracket
    heading only when its cross-track error leaves ``+-band_m`` (hysteresis), so a slanted corridor
    reads as one long "go forward" rather than left/right jitter. A segment ends once the agent is
    within ``step_m / 2`` of its end along the track. With ``face_xy`` (2,) or (K,2) the agent finally turns
    toward that point (the goal's mass centre; of several, the nearest) so the goal is in view. With ``free(p, q) -> bool`` (is the
    straight step from p to q collision-free?) a blocked step is replaced by the nearest free lattice
    heading that still makes progress along the track (narrow doors). With ``goal(p)`` (world point ->
    ``True`` / 3: deep in the cells aimed for, 2: in them, 1: in cells where ending is acceptable (the
    goal region around an inner target), ``False`` / 0: outside) a walk that stops short of the
    polyline's end (the last segment ends up to half a step early, plus the cross-track band) walks on
    along the last segment, up to ``max_extra_steps`` more steps, and ends at the first position with the best
    value; the positions are simulated exactly as the agent moves, so a goal reached here is reached
    on replay. Ends with ``STOP``; raises ``ValueError`` past ``max_actions``
    or when no heading is free.
    """
    pts = np.asarray(polyline_xy, dtype=np.float64)
    turn = np.deg2rad(turn_deg)
    pos, k = pts[0].copy(), 0  # heading = start_yaw + k * turn
    actions: list[int] = []

    def turn_to(k_new: int) -> None:
        nonlocal k
        d = int(round(float(wrap_angle((k_new - k) * turn)) / turn))
        actions.extend([LEFT] * d if d > 0 else [RIGHT] * (-d))
        k += d

    def set_heading(k_new: int) -> None:
        nonlocal k
        k = k_new

    def lattice(theta: float) -> tuple[int, int]:
        rel = k + float(wrap_angle(theta - (start_yaw + k * turn))) / turn
        return int(np.floor(rel + 1e-9)), int(np.ceil(rel - 1e-9))

    for a, b in zip(pts[:-1], pts[1:]):
        seg = b - a
        length = float(np.linalg.norm(seg))
        if length < 1e-9:
            continue
        u = seg / length
        normal = np.array([-u[1], u[0]])  # left of the track
        k_lo, k_hi = lattice(float(np.arctan2(u[1], u[0])))
        if k not in (k_lo, k_hi):
            e = float(np.dot(pos - a, normal))
            turn_to(k_lo if e > 0 else k_hi)  # k_lo drifts right (e falls), k_hi left
        while float(np.dot(pos - a, u)) < length - step_m / 2 and len(actions) < max_actions:
            e = float(np.dot(pos - a, normal))
            if k_lo != k_hi:
                if e < -band_m and k == k_lo:
                    turn_to(k_hi)
                elif e > band_m and k == k_hi:
                    turn_to(k_lo)
            if free is not None:
                k_step = _free_heading(k, (k_lo, k_hi), pos, u, start_yaw, turn, step_m, free)
                if k_step is None:
                    raise ValueError(f"no collision-free step near ({pos[0]:.2f}, {pos[1]:.2f})")
                turn_to(k_step)
            actions.append(FORWARD)
            yaw = start_yaw + k * turn
            pos = pos + step_m * np.array([np.cos(yaw), np.sin(yaw)])
    if goal is not None and len(pts) > 1:
        pos = _finish_in_goal(pts, pos, goal, max_extra_steps, step_m=step_m, start_yaw=start_yaw, turn=turn,
                              free=free, heading=lambda: k, set_heading=set_heading, turn_to=turn_to,
                              actions=actions)
    if face_xy is not None:
        faces = np.asarray(face_xy, dtype=np.float64).reshape(-1, 2)  # several: the nearest one
        d = faces[int(np.argmin(np.linalg.norm(faces - pos, axis=1)))] - pos
        if np.linalg.norm(d) > 1e-6:
            theta = float(np.arctan2(d[1], d[0]))
            turn_to(k + int(round(float(wrap_angle(theta - (start_yaw + k * turn))) / turn)))
    if len(actions) >= max_actions:
        raise ValueError(f"route needs more than {max_actions} actions")
    actions.append(STOP)
    return np.asarray(actions, dtype=np.uint8)


def _finish_in_goal(pts, pos, goal, max_steps, *, step_m, start_yaw, turn, free, heading, set_heading, turn_to,
                    actions) -> np.ndarray:
    """Extra steps (see :func:`follow_polyline`) from ``pos`` into the goal; returns the final position.

    The agent walks on along the last non-empty segment's direction ``u`` (the lattice heading bracketing
    ``u`` it already has, else the nearest; with ``free``, the nearest free heading still making progress
    along ``u``): the polyline enters the goal there, so on along it lies the goal's inside. At most
    ``max_steps`` steps, stopping once ``goal`` is reached (``True`` or 3) or no step is free; then the
    walk is cut back to the first position with the best ``goal`` value seen, so the extra steps never
    end anywhere worse than where the polyline left the agent."""
    segs = np.diff(pts, axis=0)
    lens = np.linalg.norm(segs, axis=1)
    if not (lens > 1e-9).any():
        return pos
    u = segs[np.flatnonzero(lens > 1e-9)[-1]]
    u = u / np.linalg.norm(u)

    def value(q) -> float:
        v = goal(q)
        return 3.0 if v is True or v is np.True_ else float(v)

    trail = [(value(pos), pos, len(actions), heading())]  # (goal value, position, actions so far, heading)
    for _ in range(max_steps):
        if trail[-1][0] >= 3.0:
            break
        k = heading()
        rel = k + float(wrap_angle(float(np.arctan2(u[1], u[0])) - (start_yaw + k * turn))) / turn
        bracket = (int(np.floor(rel + 1e-9)), int(np.ceil(rel - 1e-9)))
        k_step = k if k in bracket else bracket[0]
        if free is not None:
            k_step = _free_heading(k_step, bracket, pos, u, start_yaw, turn, step_m, free)
            if k_step is None:
                break
        turn_to(k_step)
        actions.append(FORWARD)
        yaw = start_yaw + heading() * turn
        pos = pos + step_m * np.array([np.cos(yaw), np.sin(yaw)])
        trail.append((value(pos), pos, len(actions), heading()))
    _, pos, n, k = max(trail, key=lambda t: t[0])  # the first of the best
    del actions[n:]
    set_heading(k)
    return pos


def _free_heading(k, bracket, pos, u, start_yaw, turn, step_m, free) -> int | None:
    """The lattice heading to step with: ``k`` when free, else the nearest free one making progress."""
    order = [k] + [b for b in bracket if b != k]
    base = bracket[0]
    for d in range(1, 7):
        order += [base - d, bracket[1] + d]
    for kk in order:
        yaw = start_yaw + kk * turn
        step = step_m * np.array([np.cos(yaw), np.sin(yaw)])
        if np.dot(step, u) > 0.2 * step_m and free(pos, pos + step):
            return kk
    return None


# ----------------------------------------------------------------------------- words

@dataclass(frozen=True)
class RoutePart:
    kind: str  # "turn left" | "turn right" | "turn around" | "go forward"
    value: float  # degrees turned (left positive) or metres forward


def route_parts(actions: np.ndarray, *, step_m: float = 0.25, turn_deg: float = 15.0, min_run: int = 3
                ) -> list[RoutePart]:
    """navchat's cut of an action sequence into route parts (see the module docstring)."""
    text = "".join(_LETTER.get(int(a), "") for a in actions)
    raw: list[RoutePart] = []
    pattern = "(" + "|".join(f"{c}{{{min_run},}}" for c in "lrf") + ")"
    for chunk in re.split(pattern, text):
        if not chunk:
            continue
        angle = turn_deg * (chunk.count("l") - chunk.count("r"))
        steps = chunk.count("f")
        if abs(angle) >= 45:
            raw.append(RoutePart("turn", angle))
            if steps >= min_run:
                raw.append(RoutePart("go forward", steps * step_m))
        elif steps:
            # a jitter chunk ("ffrff") keeps its distance; short ones merge into the next forward run
            raw.append(RoutePart("go forward", steps * step_m))
    merged = _merge_same(raw)
    # forwards too short to say vanish; the turns around them then add up
    merged = _merge_same([p for p in merged if p.kind == "turn" or p.value >= min_run * step_m - 1e-9])
    out = []
    for p in merged:
        if p.kind == "turn":
            a = float(wrap_angle(np.deg2rad(p.value))) * 180 / np.pi
            if abs(a) >= 135:
                out.append(RoutePart("turn around", a))
            elif a >= 45:
                out.append(RoutePart("turn left", a))
            elif a <= -45:
                out.append(RoutePart("turn right", a))
        else:
            out.append(p)
    return _merge_same(out)  # forwards around a dropped small turn join up


def _merge_same(parts: list[RoutePart]) -> list[RoutePart]:
    out: list[RoutePart] = []
    for p in parts:
        if out and out[-1].kind == p.kind:
            out[-1] = RoutePart(p.kind, out[-1].value + p.value)
        else:
            out.append(p)
    return out


def say_distance(metres: float) -> str:
    """``2.5 -> '2.5 meters'``, ``1 -> '1 meter'`` (nearest half metre, at least half a metre)."""
    v = max(0.5, round(metres * 2) / 2)
    num = f"{v:g}"
    return f"{num} meter" if v == 1 else f"{num} meters"


def route_text(parts: list[RoutePart]) -> str:
    """Parts in words: ``'turn left, go forward 5 meters, turn right'``."""
    return ", ".join(p.kind if p.kind != "go forward" else f"go forward {say_distance(p.value)}" for p in parts)


def procedural_allowed(parts: list[RoutePart], agent_room: str | None, goal_room: str | None, max_parts: int = 3
                       ) -> bool:
    """navchat's rule: send the route only when the goal is in another room and it has 1..max_parts parts."""
    return goal_room is not None and agent_room != goal_room and 0 < len(parts) <= max_parts


# ----------------------------------------------------------------------------- from any pose

@dataclass(frozen=True)
class RouteSettings:
    """How a :class:`RoutePlanner` plans and discretizes routes: the task's action space and planning margins
    (``task`` params), with the stop radius a planner may replace. Build it with :meth:`from_config` (no
    defaults here: the ``task`` params own them)."""

    step_m: float  # forward action, metres
    turn_deg: float  # turn action, degrees
    clearance_m: float  # planned paths keep this far from non-navigable cells
    stop_radius_m: float  # without a region, aim for cells this close to the footprint

    @classmethod
    def from_config(cls, task: TaskParams | None = None, *, step_m: float | None = None,
                    turn_deg: float | None = None, clearance_m: float | None = None,
                    stop_radius_m: float | None = None) -> RouteSettings:
        """The settings of the ``task`` section (default: the params' defaults); a keyword replaces one field
        (the evaluator: routes.zarr's action space, its agents' stop radius, 0 to aim at explicit cells)."""
        p = TaskParams() if task is None else task
        given = {"step_m": step_m, "turn_deg": turn_deg, "clearance_m": clearance_m, "stop_radius_m": stop_radius_m}
        return cls(**{name: float(getattr(p, name) if value is None else value) for name, value in given.items()})


@dataclass
class Route:
    path: GeodesicPath
    actions: np.ndarray  # (A,) uint8
    parts: list[RoutePart]

    @property
    def text(self) -> str:
        return route_text(self.parts)


class RoutePlanner:
    """Shortest routes to goals on one navigable grid; the FMM field of each goal is cached.

    ``navigable``: ``(rows, cols)`` bool. Goals are given as a footprint mask ``(rows, cols)`` bool
    or as a world point ``goal_xy`` (its cell stands for the object). ``settings`` default: the
    ``task`` params' defaults (:meth:`RouteSettings.from_config`).
    """

    def __init__(self, navigable: np.ndarray, grid: GridSpec, settings: RouteSettings | None = None):
        self.grid = grid
        self.settings = RouteSettings.from_config() if settings is None else settings
        self.navigable = np.asarray(navigable, dtype=bool)
        self.plan_mask = planning_mask(self.navigable, grid, self.settings.clearance_m)
        self._fields: dict[object, np.ndarray] = {}
        self._goals: dict[object, np.ndarray] = {}  # cells a route must end in, per (key, region)
        self._labels: dict[str, np.ndarray] = {}  # each mask's 4-connected parts (what a field can reach)
        self.raise_failures = False  # True: a route found but not drivable raises instead of returning None

    def goal_mask(self, goal_xy: np.ndarray) -> np.ndarray:
        m = np.zeros(self.navigable.shape, dtype=bool)
        rc = self.grid.world_to_cell(np.asarray(goal_xy, dtype=np.float64))
        if self.grid.inside(rc):
            m[rc[0], rc[1]] = True
        return m

    def field(self, key: object, object_mask: np.ndarray, mask_kind: str = "clear", *, region: bool = False
              ) -> np.ndarray:
        """FMM field on the clearance mask (``'clear'``) or the navigable mask to the cells within the stop
        radius of ``object_mask`` — or, with ``region=True``, to the cells of ``object_mask`` itself (a goal
        region / route target of :mod:`pipeline.nav.region`). Cached per ``(key, mask_kind, region)``."""
        ck = (key, mask_kind, bool(region))
        if ck not in self._fields:
            mask = self.plan_mask if mask_kind == "clear" else self.navigable
            radius = 0.0 if region else self.settings.stop_radius_m
            target = target_region(mask, object_mask, self.grid, radius)
            self._fields[ck] = geodesic_field(mask, target, self.grid)
        return self._fields[ck]

    def reach(self, object_mask: np.ndarray, mask_kind: str = "clear", *, region: bool = False) -> np.ndarray:
        """``(rows, cols)`` bool: where :meth:`field` of the same goal is finite, without marching it
        (:func:`pipeline.nav.fmm.reachable`, on the mask's parts found once)."""
        labels, joined = self._joined(object_mask, mask_kind, region)
        return joined[labels]

    def _joined(self, object_mask: np.ndarray, mask_kind: str, region: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(labels, joined)``: the mask's 4-connected parts ``(rows, cols)`` int32 (0 off the mask) and which of
        them the goal's field reaches ``(parts + 1,)`` bool."""
        mask = self.plan_mask if mask_kind == "clear" else self.navigable
        if mask_kind not in self._labels:
            self._labels[mask_kind] = mask_parts(mask)
        labels = self._labels[mask_kind]
        target = target_region(mask, object_mask, self.grid, 0.0 if region else self.settings.stop_radius_m)
        return labels, joined_parts(labels, target)

    def _reaches_near(self, object_mask: np.ndarray, mask_kind: str, region: bool, rc) -> bool:
        """Whether the goal's field is finite anywhere a route from cell ``rc`` may enter it (within
        :data:`ENTRY_CELLS`): when not, :meth:`route` needs no field on that mask."""
        labels, joined = self._joined(object_mask, mask_kind, region)
        r, c = int(rc[0]), int(rc[1])
        return bool(joined[labels[max(r - ENTRY_CELLS, 0): r + ENTRY_CELLS + 1,
                                  max(c - ENTRY_CELLS, 0): c + ENTRY_CELLS + 1]].any())

    def forget(self, owner: object) -> None:
        """Drop the cached fields and goal cells of key ``owner`` and of the keys ``(owner, ...)`` (a goal's aims):
        a caller done with a goal keeps memory to the goals still to plan, each field being a whole floor's grid."""
        def owned(key: object) -> bool:
            return key == owner or (isinstance(key, tuple) and len(key) > 0 and key[0] == owner)

        for cache in (self._fields, self._goals):
            for ck in [ck for ck in cache if owned(ck[0])]:
                del cache[ck]

    def route_into(self, pose_xy_yaw, cells: np.ndarray, *, key: object = None, face_xy=None,
                   end_mask: np.ndarray | None = None) -> Route | None:
        """:meth:`route` to the explicit ``cells`` ``(rows, cols)`` bool (a goal region or route target of
        :mod:`pipeline.nav.region`), not to a stop radius around them."""
        return self.route(pose_xy_yaw, cells, key=key, face_xy=face_xy, region=True, end_mask=end_mask)

    def route(self, pose_xy_yaw, object_mask: np.ndarray, *, key: object = None, face_xy=None,
              region: bool = False, end_mask: np.ndarray | None = None) -> Route | None:
        """The route from ``(x, y, yaw)`` to the goal, or ``None`` when unreachable.

        The target is the stop radius around ``object_mask``, or with ``region=True`` the cells of
        ``object_mask`` themselves. Plans on the clearance mask first; a pose or goal cut off there
        (narrow doors) is planned on the navigable mask itself. Actions are checked step by step
        against the navigable mask. The walk finishes :data:`DEEP_CELLS` inside the target where a few
        more steps along the last segment get it there (:func:`follow_polyline`'s ``goal``: the polyline
        ends on the target's first cell, where stopping half a step early leaves the agent outside it),
        else in the target or in ``end_mask`` ``(rows, cols)`` bool when given (the goal region around
        an inner target).
        """
        x, y, yaw = (float(v) for v in pose_xy_yaw)
        key = key if key is not None else hash(np.packbits(object_mask).tobytes())
        start = np.array([x, y])
        rc = self.grid.world_to_cell(start)
        if not self.grid.inside(rc):
            return None
        failure = None
        for mask_kind in ("clear", "navigable"):
            if (key, mask_kind, bool(region)) not in self._fields and \
                    not self._reaches_near(object_mask, mask_kind, region, rc):
                continue  # the field would be infinite wherever this pose can join it: not worth marching
            fld = self.field(key, object_mask, mask_kind, region=region)
            mask = self.plan_mask if mask_kind == "clear" else self.navigable
            entry = start
            if not np.isfinite(fld[rc[0], rc[1]]):
                # a pose outside the clearance band joins it at the nearest cell in straight, free reach
                near = self._nearest_finite(fld, rc, start)
                if near is None:
                    continue
                entry = self.grid.cell_to_world(near)
            path = shortest_path(fld, mask, self.grid, entry)
            if path is None:
                continue
            if not np.allclose(entry, start):
                xy = np.vstack([start, path.polyline_xy])
                path = GeodesicPath(xy, path.geodesic_m + float(np.hypot(*(entry - start))),
                                    GeodesicPath.polyline_length(xy))
            s = self.settings
            aim, deep = self.goal_cells(key, object_mask, region=region)
            try:
                actions = follow_polyline(path.polyline_xy, yaw, step_m=s.step_m, turn_deg=s.turn_deg,
                                          face_xy=face_xy, free=self.step_free,
                                          goal=lambda p, deep=deep, aim=aim: 3 if self.grid.holds(deep, p) else
                                          2 if self.grid.holds(aim, p) else
                                          int(end_mask is not None and self.grid.holds(end_mask, p)))
            except ValueError as err:  # boxed in on this mask: try the next one
                failure = err
                continue
            return Route(path, actions, route_parts(actions, step_m=s.step_m, turn_deg=s.turn_deg))
        if failure is not None and self.raise_failures:
            raise failure
        return None

    def goal_cells(self, key: object, object_mask: np.ndarray, *, region: bool = False
                   ) -> tuple[np.ndarray, np.ndarray]:
        """``(aim, deep)`` ``(rows, cols)`` bool: the cells a route aims for (the navigable cells of
        ``object_mask`` (``region``) or within the stop radius of it) and those :data:`DEEP_CELLS` inside
        them (the aim itself where none are), where a walk finishes when it can. Cached per ``(key, region)``."""
        ck = (key, bool(region))
        if ck not in self._goals:
            radius = 0.0 if region else self.settings.stop_radius_m
            aim = target_region(self.navigable, object_mask, self.grid, radius)
            deep = np.zeros_like(aim)
            if aim.any():  # eroded on the aim's box and a border (outside it, erosion leaves nothing)
                rr, cc = np.nonzero(aim)
                win = (slice(max(int(rr.min()) - DEEP_CELLS - 1, 0), int(rr.max()) + DEEP_CELLS + 2),
                       slice(max(int(cc.min()) - DEEP_CELLS - 1, 0), int(cc.max()) + DEEP_CELLS + 2))
                deep[win] = ndimage.binary_erosion(aim[win], iterations=DEEP_CELLS)
            self._goals[ck] = (aim, deep if deep.any() else aim)
        return self._goals[ck]

    def step_free(self, p: np.ndarray, q: np.ndarray) -> bool:
        """Is the straight move from world point ``p`` to ``q`` inside the navigable mask?"""
        x0, y1 = self.grid.origin_xy
        cs = self.grid.cell_size_m  # continuous (row, col), cell centres at integers
        px, py, qx, qy = float(p[0]), float(p[1]), float(q[0]), float(q[1])
        return one_segment_free(self.navigable, (y1 - py) / cs - 0.5, (px - x0) / cs - 0.5,
                                (y1 - qy) / cs - 0.5, (qx - x0) / cs - 0.5)

    def _nearest_finite(self, fld: np.ndarray, rc: np.ndarray, start_xy: np.ndarray, radius_cells: int = ENTRY_CELLS
                        ) -> np.ndarray | None:
        r0, c0 = int(rc[0]), int(rc[1])
        rs = slice(max(r0 - radius_cells, 0), r0 + radius_cells + 1)
        cs = slice(max(c0 - radius_cells, 0), c0 + radius_cells + 1)
        rr, cc = np.nonzero(np.isfinite(fld[rs, cs]))
        if rr.size == 0:
            return None
        rr, cc = rr + rs.start, cc + cs.start
        for k in np.argsort((rr - r0) ** 2 + (cc - c0) ** 2, kind="stable")[:50]:
            cell = np.array([rr[k], cc[k]])
            if self.step_free(start_xy, self.grid.cell_to_world(cell)):
                return cell
        return None


def procedural_instruction(navigable: np.ndarray, grid: GridSpec, pose_xy_yaw, goal_xy, *,
                           object_mask: np.ndarray | None = None, settings: RouteSettings | None = None,
                           planner: RoutePlanner | None = None) -> str | None:
    """The procedural feedback from ``pose_xy_yaw`` = (x, y, yaw) (world metres, radians) to the goal.

    ``goal_xy`` is the goal's mass centre (world); ``object_mask`` its footprint on the grid (default:
    the cell of ``goal_xy``). Pass a :class:`RoutePlanner` to reuse cached FMM fields across calls.
    Returns ``None`` when the goal cannot be reached from the pose.
    """
    planner = planner or RoutePlanner(navigable, grid, settings)
    mask = object_mask if object_mask is not None else planner.goal_mask(goal_xy)
    route = planner.route(pose_xy_yaw, mask, face_xy=np.asarray(goal_xy, dtype=np.float64))
    return None if route is None else route.text
