"""ORION's modules as a Python API with the paper's function names and returns.

One :class:`Modules` per episode, on top of the scene's shared :class:`~orion_eval.scene.SceneContext`:

- control: ``move(dist_m)``, ``rotate(angle_rad)``, ``goto_point(xy)`` (FMM planner on the navigable
  grid), ``goto_object(obj_id)``;
- semantic map: ``retrieve_map(obj_str) -> [(obj_id, distance_m, angle_rad)]`` (VLMap or CF map);
- detection: ``detect_object(obj_str) -> [(obj_id, distance_m, angle_rad)]`` on the ego view
  ray-cast from the reconstructed mesh, with the agent's detector (:attr:`Modules.detector`: ORION's grounded
  one or CoW's CLIP saliency); ``double_check(obj_id) -> bool``; ``check_attributes(obj_id, name, description)``
  (does the object in view have the described colour / material), ``read_around`` (the same reading from the look
  around just made);
- exploration: ``search_object(obj_str) -> obj_id | None`` (spin first, then frontiers, the view ahead watched
  every :data:`WATCH_STEPS` forward steps on the way; ``search_objects`` for several things at once); a spin is
  remembered where it was made (no steps to repeat it there);
- memory: ``update_memory(obj_id, pos_str, neg_str)``, ``retrieve_memory(obj_str) -> [(obj_id, d, a)]``;
- interaction: ``talk(content) -> str`` (the user's reply).

Distances are metres from the agent to the object's nearest cell; angles are the bearing of the
object's centre relative to the agent's heading (counter-clockwise positive). Objects get ids in
the episode's registry; a new sighting within ``MERGE_M`` of a known object is that object.
Every action goes through :class:`~orion_eval.episode.EpisodeRun`, which counts steps and Talk turns
and ends the episode by raising :class:`~orion_eval.episode.EpisodeOver`.

In a building every module works per floor. Each found object has its floor (:attr:`FoundObject.floor`; sightings
merge on one floor only); ``retrieve_map`` answers from every floor's map; detection and line of sight use the
agent's floor's ego view; exploration keeps an explored mask per floor, and a search that has no frontier left on
its floor takes the stairs to the nearest floor it has not explored to the end (:meth:`Modules.floor_to_explore`);
memory paints each floor's cells apart. ``goto_object`` on another floor and ``take_stairs`` walk to the nearest
stair leading there, face along it and climb it with forward steps (the world's stairs: :mod:`orion_eval.world`).
On a single floor all of this is floor 0 and nothing changes.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial.distance import cdist

from orion_eval.memory import MemoryMaps
from orion_eval.nav import points_round
from pipeline.nav.actions import FORWARD, LEFT, RIGHT, wrap_angle
from pipeline.scene import MAP_NAMES

MERGE_M = 0.6
#: while exploring, the detector looks at the view ahead every this many forward steps (ORION's exploration
#: "perceives on-the-fly" on the way to each frontier, as CoW's detector runs on its observations)
WATCH_STEPS = 4
#: a walk to a stair blocked on the way is planned again from where it stopped at most this many times
CLIMB_REPLANS = 3
#: metres from a landmark's centre to the points its other sides are looked at from (:meth:`Modules.sides_of`): a goal
#: "next to" it (footprints within goals.landmark_radius_m) is in reach of the view from there
SIDE_M = 1.5


def new_memory(ctx) -> MemoryMaps:
    """An empty ORION memory on the scene's ORION map text encoder."""
    return MemoryMaps(lambda texts: np.asarray(ctx.scene.map_query(ctx.params.eval.orion_map).text_features(texts)),
                      merge_m=MERGE_M)


@dataclass
class FoundObject:
    """An object the agent has found in this episode (from a map, a detection...); not a goals-document object."""

    obj_id: int
    center_xy: np.ndarray
    cells: np.ndarray  # flat cell ids
    source: str  # 'vlmap' | 'cfmap' | 'detect' | ...
    score: float = 0.0
    texts: set = field(default_factory=set)
    floor: int = 0  # the floor it lies on (its cells are on that floor's grid)

    @property
    def from_map(self) -> bool:
        """Found by a semantic map's retrieval (first registered from the vlmap or the cfmap)."""
        return self.source in MAP_NAMES


class Modules:
    """The ORION API for one episode (see the module docstring)."""

    def __init__(self, run, memory: MemoryMaps | None = None):
        self.run = run  # EpisodeRun: body, ctx, act(), talk()
        self.ctx = run.ctx
        self.objects: dict[int, FoundObject] = {}
        # a memory carried across the goals of a scene (evaluate_scene), else a fresh one
        self.memory = memory if memory is not None else new_memory(self.ctx)
        self._explored: dict[int, np.ndarray] = {}  # floor -> explored cells of its planner's cropped grid
        self._spins: dict[tuple[int, int], dict[str, list[int]]] = {}  # place -> what its spin saw, per query
        # which ego-view detector detect_object runs: 'grounded' (ORION's) or 'saliency' (CoW's CLIP Grad-CAM);
        # the agent sets it from its module set
        self.detector = "grounded"

    # ------------------------------------------------------------------ registry
    @property
    def pose(self):
        return self.run.body.pose

    @property
    def floor(self) -> int:
        """The floor the agent stands on."""
        return self.run.body.floor

    @property
    def here(self):
        """The :class:`~orion_eval.scene.Level` of the agent's floor (its planners, grids and success rule)."""
        return self.ctx.level(self.floor)

    def register(self, center_xy, cells, source: str, score: float = 0.0, text: str | None = None,
                 floor: int | None = None) -> int:
        """The id of the object at ``center_xy`` on ``floor`` (default: the agent's): a known one within
        :data:`MERGE_M` on that floor, else a new one."""
        c = np.asarray(center_xy, np.float64)
        floor = self.floor if floor is None else int(floor)
        for e in self.objects.values():
            if e.floor == floor and np.linalg.norm(e.center_xy - c) <= MERGE_M:
                if text:
                    e.texts.add(text)
                return e.obj_id
        oid = len(self.objects) + 1
        self.objects[oid] = FoundObject(oid, c, np.asarray(cells, np.int64), source, score, {text} if text else set(),
                                        floor)
        return oid

    def footprint_points(self, obj_id: int) -> np.ndarray:
        """``(K,2)`` world points of an object's cells, about 64 of them (its centre when it has no cells)."""
        e = self.objects[obj_id]
        rr, cc = np.divmod(e.cells[:: max(1, len(e.cells) // 64)], self.ctx.grid.cols)
        return self.ctx.grid.cell_to_world(np.stack([rr, cc], axis=1)) if len(rr) else e.center_xy[None]

    def relative(self, obj_id: int) -> tuple[float, float]:
        """(distance_m to the nearest cell, bearing of the centre) of an object from the agent."""
        e = self.objects[obj_id]
        x, y, yaw = self.pose
        xy = self.footprint_points(obj_id)
        d = float(np.min(np.hypot(xy[:, 0] - x, xy[:, 1] - y)))
        a = float(wrap_angle(math.atan2(e.center_xy[1] - y, e.center_xy[0] - x) - yaw))
        return d, a

    def _triples(self, ids: list[int]) -> list[tuple[int, float, float]]:
        out = [(i, *self.relative(i)) for i in dict.fromkeys(ids)]
        return sorted(out, key=lambda t: (t[1], t[0]))

    # ------------------------------------------------------------------ control
    def move(self, dist_m: float) -> None:
        """Walk straight ahead; a step into a wall ends the walk (the agent stays put: steps after it would too)."""
        for _ in range(max(0, int(round(dist_m / self.ctx.step_m)))):
            if not self.run.act(FORWARD):
                return

    def rotate(self, angle_rad: float) -> None:
        n = int(round(float(wrap_angle(angle_rad)) / math.radians(self.ctx.turn_deg)))
        for _ in range(abs(n)):
            self.run.act(LEFT if n > 0 else RIGHT)

    def _follow(self, route, watch=None, *, stop_blocked: bool = False) -> bool:
        """Walk ``route``'s actions; ``watch()`` is called after every :data:`WATCH_STEPS` th forward step and stops
        the walk when it returns True. False when there is no route, or (``stop_blocked``) when a forward step
        collided: the walk ends there, as a robot's planner gives up a blocked goal, instead of walking the rest of
        its actions from the wrong place (an exploration that walked on from it could retry the same blocked
        frontier until the step budget). A planner's route does not collide in the evaluation's world (the world
        tests steps as the planners do, :class:`~orion_eval.scene.SceneContext`); a changed world would."""
        if route is None:
            return False
        forward = 0
        for a in route.actions.tolist():
            if a == 0:
                break
            if not self.run.act(a) and stop_blocked:
                return False
            if watch is not None and a == FORWARD:
                forward += 1
                if forward % WATCH_STEPS == 0 and watch():
                    break
        return True

    def leave_stair(self) -> None:
        """Walk off a stair the agent stands on (a walk that stopped on it: "go forward 2 meters" from its end), on
        along it to the end it faces (up when facing across it): the planners plan on the floors, not on stairs."""
        body = self.run.body
        if body.stair is None:
            return
        way = self.ctx.world.stairs[body.stair[0]]
        down = abs(float(wrap_angle(self.pose[2] - way.up_heading - math.pi))) <= math.radians(self.ctx.turn_deg) / 2
        if not down:
            self.rotate(way.up_heading - self.pose[2])
        for _ in range(way.steps + 1):
            if body.stair is None or not self.run.act(FORWARD):
                return

    def goto_point(self, xy, watch=None, floor: int | None = None) -> bool:
        """Walk to (near) a world point (on ``floor``: the stairs first when it is not the agent's); False when
        unreachable or blocked (:meth:`_follow`). ``watch``: see :meth:`_follow`."""
        self.leave_stair()
        if floor is not None and floor != self.floor and not self.take_stairs(floor):
            return False
        planner = self.here.planner
        mask = planner.point_mask(xy)
        rc = self.ctx.grid.world_to_cell(np.asarray(xy, np.float64))
        route = planner.route(self.pose, mask, key=("pt", int(rc[0]), int(rc[1])), face_xy=None)
        return self._follow(route, watch, stop_blocked=True)

    def take_stairs(self, floor: int) -> bool:
        """Go to ``floor`` over the stairs, a flight at a time: walk to the end of the nearest stair (geodesic, then
        straight-line distance) that leads a floor nearer, face along it and climb it with forward steps. False when
        no stair leads on from here, or a walk or climb is blocked (the agent stays where that left it)."""
        self.leave_stair()
        while self.floor != floor:
            here = self.floor
            nxt = here + (1 if floor > here else -1)
            if not any(self._climb(way, here, nxt) for way in self._stairs_between(here, nxt)):
                return False
        return True

    def _stairs_between(self, here: int, nxt: int) -> list:
        """The stairs joining floors ``here`` and ``nxt``, nearest the agent first (geodesic on the clearance band,
        then straight-line: an agent beside a wall is off the band, where the geodesic is unknown)."""
        planner = self.here.view_planner
        ways = [w for w in self.ctx.world.stairs if {w.link.lower, w.link.upper} == {here, nxt}]
        xy = np.asarray(self.pose[:2], np.float64)
        return sorted(ways, key=lambda w: (planner.geodesic(self.pose, w.ends[here], key=("stair", w.link.id)),
                                           float(np.hypot(*(np.asarray(w.link.end_on(here)) - xy)))))

    def _climb(self, way, here: int, nxt: int) -> bool:
        """Walk to ``way``'s end on ``here``, face along it and climb to ``nxt``; False when that fails."""
        lk, planner = way.link, self.here.view_planner
        near, far = np.asarray(lk.end_on(here), np.float64), np.asarray(lk.end_on(nxt), np.float64)
        self.run.log_event("stairs", f"{'up' if nxt > here else 'down'} {lk.id} to floor {nxt}")
        if not way.at_end(here, *self.pose[:2]):
            # a walk blocked on the way (a planner's step judged free a hair from a wall) is planned again from where
            # it stopped, up to CLIMB_REPLANS times: the stairs are the only way on
            for _ in range(CLIMB_REPLANS):
                route = planner.route(self.pose, way.ends[here], key=("stair", lk.id), face_xy=far)
                if route is None:
                    return False
                if self._follow(route, stop_blocked=True):
                    break
            else:
                return False
            # a walk on the heading lattice can end a step beside the few cells around the stair's end
            last = planner.approach(self.pose, way.ends[here])
            if last is None:
                return False
            for a in last:
                self.run.act(a)
        self.rotate(math.atan2(far[1] - near[1], far[0] - near[0]) - self.pose[2])
        for _ in range(way.steps + 1):
            if self.floor == nxt or not self.run.act(FORWARD):
                break
        return self.floor == nxt

    def goto_object(self, obj_id: int) -> bool:
        """Walk into the object's goal region (the routes module's definition: within the success distance of
        its cells, centre in line of sight), face its centre; False when unreachable or blocked
        (:meth:`_follow`). An object on another floor is walked to over the stairs (:meth:`take_stairs`)."""
        e = self.objects[obj_id]
        self.leave_stair()
        if e.floor != self.floor and not self.take_stairs(e.floor):
            return False
        g = self.ctx.grid
        mask = np.zeros(g.rows * g.cols, bool)
        mask[e.cells] = True
        # sight the object's centre column at half and full height of its reconstructed top surface
        h = self.here.height.reshape(-1)[e.cells] if len(e.cells) else np.array([np.nan])
        top = float(np.clip(np.nanmedian(h), 0.1, 2.0)) if np.isfinite(h).any() else 0.6
        # the scene caches the region and the planner its field by this key: it names all the target depends on
        # (two sightings of one object can share their cells' count and first cell, not their cells and centre)
        key = ("obj", hashlib.blake2b(np.ascontiguousarray(e.cells, np.int64).tobytes()
                                      + np.asarray(e.center_xy, np.float64).tobytes(), digest_size=16).hexdigest())
        region, view = self.ctx.goal_target(key, mask.reshape(g.rows, g.cols), e.center_xy, (0.5 * top, top),
                                            self.floor)
        route = self.here.view_planner.route(self.pose, view, key=key, face_xy=e.center_xy, end_mask=region)
        return self._follow(route, stop_blocked=True)

    # ------------------------------------------------------------------ semantic map
    def retrieve_map(self, obj_str: str, which: str = "vlmap") -> list[tuple[int, float, float]]:
        """The map's candidates of ``obj_str`` on every floor (each floor's map), as ``(obj_id, d, a)``."""
        ids = [self.register(m.center_xy, m.cells, which, m.score, obj_str, floor=f)
               for f in self.ctx.floor_ids for m in self.ctx.map_objects(which, obj_str, f)]
        return self._triples(ids)

    def map_scores(self, obj_str: str, which: str) -> dict[int, float]:
        """obj_id -> map score of ``obj_str`` (registering the candidates of every floor)."""
        return {self.register(m.center_xy, m.cells, which, m.score, obj_str, floor=f): m.score
                for f in self.ctx.floor_ids for m in self.ctx.map_objects(which, obj_str, f)}

    # ------------------------------------------------------------------ detection
    def detect_object(self, obj_str: str) -> list[tuple[int, float, float]]:
        self.run.log_event("detect", obj_str)
        ids = [self.register(d.center_xy, d.cells, "detect", d.score, obj_str) for d in self.ctx.detect(self.pose, obj_str, self.detector)]
        return self._triples(ids)

    def double_check(self, obj_id: int) -> bool:
        """Face the object and check the ego view detects something matching the object's query there."""
        self.rotate(self.relative(obj_id)[1])
        return any(self._detects_at(obj_id, text) for text in sorted(self.objects[obj_id].texts) or [""])

    def _detects_at(self, obj_id: int, text: str, own: bool = False) -> bool:
        """Whether the current ego view detects ``text`` at the object (:meth:`_sights`)."""
        if self.objects[obj_id].floor != self.floor:
            return False  # not on the floor the agent looks at
        return any(self._sights(obj_id, det.center_xy, det.cells, own)
                   for det in self.ctx.detect(self.pose, text, self.detector))

    def _sights(self, obj_id: int, center_xy: np.ndarray, cells: np.ndarray, own: bool, also: int = 0) -> bool:
        """Whether a detection (its centre and cells) is a sighting of the object: within 1 m of its centre or on one
        of its cells. ``own``: and no other object of the episode (but ``also``, the detection's own entry) is nearer
        it (a detection is the nearest known object's: a chair beside the goal seen as "chair" is that chair's)."""
        e = self.objects[obj_id]
        others = (np.array([o.center_xy for o in self.objects.values()
                            if o.obj_id not in (obj_id, also) and o.floor == e.floor]).reshape(-1, 2)
                  if own else np.empty((0, 2)))
        d = float(np.linalg.norm(np.asarray(center_xy) - e.center_xy))
        return (d <= 1.0 or bool(np.isin(cells, e.cells).any())) and not (
            len(others) and float(np.min(np.hypot(*(others - center_xy).T))) < d)

    def check_attributes(self, obj_id: int, name: str, description: str) -> bool | None:
        """Face the object and read it with the ego-view detector: True when the view detects ``description``
        there, False when it detects ``name`` but not the description (the object is seen, and its colour or
        material is not the described one), None when neither (not seen well enough to tell). Only the object's
        own sightings count: one nearer another object the agent knows of is that object's."""
        self.rotate(self.relative(obj_id)[1])
        self.run.log_event("verify", description)
        if self._detects_at(obj_id, description, own=True):
            return True
        return False if self._detects_at(obj_id, name, own=True) else None

    def read_around(self, obj_id: int, name: str, description: str) -> bool | None:
        """The reading of :meth:`check_attributes` from the look around made where the agent stands (remembered: no
        steps when it looked for both there, which :meth:`look_around_for` otherwise does): True when one of its
        sightings of ``description`` is the object's, False when it saw the object as ``name`` only, None when it saw
        neither there. Only the object's own sightings count."""
        seen = self.look_around_for([description, name])
        self.run.log_event("verify", description)

        def sighted(text: str) -> bool:
            return any(self._sights(obj_id, self.objects[i].center_xy, self.objects[i].cells, True, also=i)
                       for i, _, _ in seen[text] if self.objects[i].floor == self.objects[obj_id].floor)

        if sighted(description):
            return True
        return False if sighted(name) else None

    # ------------------------------------------------------------------ exploration
    def _explored_mask(self, floor: int | None = None) -> np.ndarray:
        """The explored cells of ``floor`` (default: the agent's), on its planner's cropped grid."""
        floor = self.floor if floor is None else floor
        if floor not in self._explored:
            cg = self.ctx.level(floor).planner.crop_grid
            self._explored[floor] = np.zeros((cg.rows, cg.cols), bool)
        return self._explored[floor]

    def _mark_explored(self) -> None:
        cg = self.here.planner.crop_grid
        r = self.ctx.params.eval.explore_radius_m
        rc = cg.world_to_cell(np.asarray(self.pose[:2]))
        n = int(math.ceil(r / cg.cell_size_m))
        rr, cc = np.mgrid[-n : n + 1, -n : n + 1]
        keep = (rr**2 + cc**2) * cg.cell_size_m**2 <= r * r
        rr, cc = rr[keep] + rc[0], cc[keep] + rc[1]
        ok = (rr >= 0) & (rr < cg.rows) & (cc >= 0) & (cc < cg.cols)
        self._explored_mask()[rr[ok], cc[ok]] = True

    def look_around(self, obj_str: str) -> list[tuple[int, float, float]]:
        """Spin 360 deg in turn steps, detecting every 90 deg (the ego view is 90 deg wide)."""
        return self.look_around_for([obj_str])[obj_str]

    def look_around_for(self, obj_strs: list[str]) -> dict[str, list[tuple[int, float, float]]]:
        """One 360 deg spin detecting each of ``obj_strs`` in every view: ``{obj_str: [(obj_id, d, a)]}``.

        The agent remembers what each spin saw where it stood: looking around again at the same place for
        what it already looked for there costs no steps and gives the same objects (the views are the same)."""
        seen = self._spins.setdefault(self.ctx.pose_key(self.pose)[:2], {})
        new = [s for s in dict.fromkeys(obj_strs) if s not in seen]
        if new:
            found: dict[str, list[int]] = {s: [] for s in new}
            per_view = max(1, int(round(90.0 / self.ctx.turn_deg)))
            views = int(round(360.0 / self.ctx.turn_deg)) // per_view
            for _ in range(views):
                for s in new:
                    found[s] += [t[0] for t in self.detect_object(s)]
                for _ in range(per_view):
                    self.run.act(LEFT)
            seen.update(found)
        cg = self.here.planner.crop_grid  # the agent's floor's (a building's floors have their own)
        if new or not self._explored_mask()[tuple(cg.world_to_cell(np.asarray(self.pose[:2])))]:
            self._mark_explored()  # a spin remembered here covers its place again after the exploration restarted
        return {s: self._triples(seen[s]) for s in obj_strs}

    def sides_of(self, xy, start, radius: float = SIDE_M) -> list[np.ndarray]:
        """Points to look at the object at ``xy`` from on its other sides than ``start``'s, on the agent's floor
        (:func:`orion_eval.nav.points_round`)."""
        return points_round(self.here.navigable, self.ctx.grid, xy, start, radius)

    def restart_exploration(self) -> None:
        """Forget which places the exploration has covered (not what each spin saw there): the next search starts
        over from where the agent stands, its nearest frontiers first. CoW's exploration does so when its target
        changes (navchat's ``search_object`` for CoW: a target other than the last one resets the frontier map,
        ``fbe.reset(reset_floor=True)``, and spins first), so a search for the goal after one for a landmark explores
        outward from the landmark again instead of only the frontiers the landmark search left."""
        self._explored.clear()  # every floor's: CoW's reset forgets its whole frontier map

    def frontier(self, near: np.ndarray | None = None) -> np.ndarray | None:
        """World xy of the nearest frontier cell (navigable, unexplored, next to explored) at least 1 m away; with
        ``near`` ((K,2) points the goal is said to be near: a landmark found, a route's end), the frontier nearest
        them in whole metres first (the goal is searched around what points to it), then the nearest the agent."""
        nav = self.here.planner.planner.plan_mask
        ex = self._explored_mask()
        front = nav & ~ex & ndimage.binary_dilation(ex)
        if not front.any():
            return None
        cg = self.here.planner.crop_grid
        rr, cc = np.nonzero(front)
        xy = cg.cell_to_world(np.stack([rr, cc], axis=1))
        d = np.hypot(xy[:, 0] - self.pose[0], xy[:, 1] - self.pose[1])
        far = d >= 1.0
        if not far.any():
            return None
        idx = np.flatnonzero(far)
        if near is not None and len(near):
            hint = np.round(cdist(xy[idx], np.asarray(near, np.float64).reshape(-1, 2)).min(axis=1))
            k = int(idx[np.lexsort((d[idx], hint))[0]])
        else:
            k = int(idx[np.argmin(d[idx])])
        return xy[k]

    def search_object(self, obj_str: str, skip=lambda obj_id: False) -> int | None:
        """Frontier-based exploration with a spin first; the nearest detection not ``skip``-ped, or None."""
        hit = self.search_objects([obj_str], {obj_str: skip})
        return hit[1] if hit else None

    def search_objects(self, obj_strs: list[str], skip: dict | None = None,
                       near: np.ndarray | None = None) -> tuple[str, int] | None:
        """:meth:`search_object` for several things at once (every spin detects all of them): ``(obj_str,
        obj_id)`` of the first of ``obj_strs`` (in their order) seen at the first place any was (in a spin, or in
        a look at the view ahead every :data:`WATCH_STEPS` forward steps on the way to a frontier), or None;
        ``skip`` maps an obj_str to the test of detections of it to pass over (none: keep all); ``near``: the
        frontiers nearest these points first (:meth:`frontier`)."""
        skip = skip or {}

        def keep(s: str, hits: list) -> list:
            return [t for t in hits if not skip.get(s, lambda obj_id: False)(t[0])]

        found: list = []  # what a look on the way to a frontier saw

        def watch() -> bool:
            for s in obj_strs:
                hits = keep(s, self.detect_object(s))
                if hits:
                    found.append((s, hits[0][0]))
                    return True
            return False

        for _ in range(self.ctx.params.eval.explore_max_targets):
            seen = self.look_around_for(obj_strs)
            for s in obj_strs:
                hits = keep(s, seen[s])
                if hits:
                    return s, hits[0][0]
            target = self.frontier(near)
            if target is None:
                other = self.floor_to_explore()
                if other is None or not self.take_stairs(other):
                    return None
                continue  # a spin where the stairs arrive, then that floor's frontiers
            if not self.goto_point(target, watch):
                self._explored_mask()[tuple(self.here.planner.crop_grid.world_to_cell(target))] = True
            if found:
                return found[0]
        return None

    def floor_to_explore(self) -> int | None:
        """The floor nearest the agent's (fewest flights; the lower first) that stairs join to it and that it has
        not explored to the end (never looked around on, or frontiers left); None on a single floor or when every
        floor is explored."""
        if not self.ctx.is_building:
            return None
        joined = {f for w in self.ctx.world.stairs for f in (w.link.lower, w.link.upper)}
        for f in sorted((f for f in self.ctx.floor_ids if f != self.floor and f in joined),
                        key=lambda f: (abs(f - self.floor), f)):
            ex = self._explored.get(f)
            if ex is None or (self.ctx.level(f).planner.planner.plan_mask & ~ex & ndimage.binary_dilation(ex)).any():
                return f
        return None

    def can_explore(self, near: np.ndarray | None = None) -> bool:
        """Whether a search can go on: a frontier on the agent's floor, or another floor to explore."""
        return self.frontier(near) is not None or self.floor_to_explore() is not None

    # ------------------------------------------------------------------ memory
    def _cells_offset(self, floor: int) -> int:
        """Memory paints floor ``floor``'s flat cells shifted by this much (each floor's cells apart; 0 on floor 0)."""
        return floor * self.ctx.grid.rows * self.ctx.grid.cols

    def update_memory(self, obj_id: int, pos_str: str | None, neg_str: str | None) -> None:
        e = self.objects[obj_id]
        self.memory.update(self.memory.region_key(e.center_xy, e.floor), e.cells + self._cells_offset(e.floor),
                           pos_str, neg_str)

    def retrieve_memory(self, obj_str: str) -> tuple[list[tuple[int, float, float]], list[int]]:
        """(positive hits as (obj_id, distance, angle), negative obj_ids) of ``obj_str``; remembered regions
        (possibly from earlier goals of the scene) are registered as this episode's objects."""
        pos, neg = self.memory.retrieve(obj_str)
        mem = self.memory

        def as_ids(keys):
            return [self.register(mem.centers[k], mem.regions[k] - self._cells_offset(mem.floors.get(k, 0)), "memory",
                                  text=obj_str, floor=mem.floors.get(k, 0)) for k in keys]
        return self._triples(as_ids(pos)), as_ids(neg)

    # ------------------------------------------------------------------ interaction
    def talk(self, content: str) -> str:
        return self.run.talk(content)
