"""Objects -> personalized goals with feedback: selection, names, FB, and applying user edits.

:func:`build_scene_goals` is the work of the ``goals`` stage: objects of one scene (GT in frames.zarr, a
user file, or navchat annotations; :func:`load_objects`) -> ``goals.zarr``. Landmark line of sight
uses the GT walls when the scene is simulated, else recon's occupied cells outside object footprints
(:func:`wall_grid`); procedural text starts from the recording's first camera pose (:func:`start_pose`)
and ends in the goal's region (:class:`GoalRegions`: :func:`pipeline.nav.region.group_region`, line
of sight on ``recon_mesh.ply``), planned as the routes stage plans its episodes. The regions are
computed here, once, and stored with the goals; the routes stage and the evaluator read them. A user
edit (``goals.edits[scene]``, written by ``zipon goals import``) replaces the generated document after
it is checked against the scene's objects. Format:
:mod:`pipeline.goals.store`.

Its core is one pure function, :func:`build_goals`, from plain inputs (objects, grid, wall/navigable
arrays, a start pose, settings) to a :class:`~pipeline.goals.schema.GoalsDocument` plus the
structured landmarks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy import ndimage

from pipeline.config import GoalsParams, TaskParams
from pipeline.errors import ConfigError, InputDataError, StageError
from pipeline.frames import FrameStore
from pipeline.geometry import GridSpec, camera_yaw
from pipeline.goals.feedback import FEEDBACK_KINDS, FeedbackContext, GoalDraft
from pipeline.goals.feedback.landmark import find_landmarks
from pipeline.goals.floors import (START_SNAP_MIN_M, Building, FloorParts, blind_radius_m, floor_object_index,
                                   floors_of_objects, walkable_start)
from pipeline.goals.naming import assign_rooms, ensure_unique, personalize, same_goal_groups
from pipeline.goals.navchat import check_navchat_coverage, import_navchat, navchat_frame
from pipeline.goals.objects import ObjectSet, objects_from_file, objects_from_gt, rasterize_polygons
from pipeline.goals.schema import (Feedback, GoalEntry, GoalsDocument, ObjectEntry, RoomEntry,
                                   check_against_objects, document_digest, load_document)
from pipeline.goals.store import write_goals
from pipeline.recon import OCCUPIED, UNKNOWN, Recon
from pipeline.nav.actions import RoutePlanner, RouteSettings
from pipeline.nav.region import (OWN_DILATION_CELLS, SIGHT_LEVELS, SIGHT_METHOD, group_region,
                                 recorded_camera_height, sight_window)
from pipeline.nav.sight import WindowedSight
from pipeline.scene_gt import GTScene

GOAL_TYPES = ("big", "small", "ambiguous")
AMBIGUOUS_MIN_GROUPS = 3  # ambiguous goals come first from classes with this many distinguishable instances


@dataclass
class GoalsResult:
    document: GoalsDocument
    landmarks: dict[str, list[dict]]  # goal id -> [{object, relation, distance_m}]
    object_index: np.ndarray | list[np.ndarray]  # (rows, cols) int32, 1 + index into objects.objects, 0 none;
    edited: bool = False                         # a building: one per floor


def group_type(cls_groups: int, size: str) -> str:
    """ambiguous when the class has other distinguishable instances in the scene, else its size."""
    return "ambiguous" if cls_groups > 1 else size


def spread_ambiguous(pool: list[tuple[str, ...]], cls_of: dict, per_cls: dict[str, int]) -> list[tuple[str, ...]]:
    """The seeded ambiguous pool reordered so the first picks come from classes with at least
    :data:`AMBIGUOUS_MIN_GROUPS` groups (the hard goals: "Alice's chair" among 3-6 chairs), one group per
    class in turn (classes in their seeded order of first appearance), then the other classes likewise."""
    first: dict[str, int] = {}
    turn: dict[str, int] = {}
    ranked = []
    for g in pool:
        c = cls_of[g]
        first.setdefault(c, len(first))
        turn[c] = turn.get(c, -1) + 1
        ranked.append(((per_cls[c] < AMBIGUOUS_MIN_GROUPS, turn[c], first[c]), g))
    return [g for _, g in sorted(ranked, key=lambda t: t[0])]


def select_groups(objset: ObjectSet, groups: list[tuple[str, ...]], s: GoalsParams, rng: np.random.Generator
                  ) -> list[tuple[tuple[str, ...], str]]:
    """Goal groups with their type, the paper's mix of big, small and ambiguous, seeded."""
    by_key = objset.by_key()
    per_cls: dict[str, int] = {}
    for g in groups:
        per_cls[by_key[g[0]].cls] = per_cls.get(by_key[g[0]].cls, 0) + 1
    pools: dict[str, list[tuple[str, ...]]] = {t: [] for t in GOAL_TYPES}
    for g in groups:
        o = by_key[g[0]]
        if o.cls in s.exclude_classes:
            continue
        pools[group_type(per_cls[o.cls], o.size)].append(g)
    for t in GOAL_TYPES:
        pools[t] = [pools[t][i] for i in rng.permutation(len(pools[t]))]
    pools["ambiguous"] = spread_ambiguous(pools["ambiguous"], {g: by_key[g[0]].cls for g in groups}, per_cls)
    total = min(s.max_goals, sum(len(p) for p in pools.values()))
    weights = np.asarray(s.mix, dtype=np.float64)
    want = np.floor(weights / weights.sum() * total).astype(int)
    for i in np.argsort(-(weights / weights.sum() * total - want), kind="stable")[: total - want.sum()]:
        want[i] += 1
    chosen: list[tuple[tuple[str, ...], str]] = []
    for t, n in zip(GOAL_TYPES, want):
        chosen += [(g, t) for g in pools[t][:n]]
    # a short pool's share goes to the others, in type order
    leftovers = [(g, t) for t in GOAL_TYPES for g in pools[t][int(want[GOAL_TYPES.index(t)]):]]
    chosen += leftovers[: total - len(chosen)]
    return sorted(chosen, key=lambda gt: gt[0][0])


def build_goals(objset: ObjectSet, grid: GridSpec, walls: np.ndarray, *, planner=None,
                start_pose: tuple[float, float, float] | None = None, settings: GoalsParams = GoalsParams(),
                edits: GoalsDocument | None = None, edits_path=None, goal_region=None,
                building: Building | None = None) -> GoalsResult:
    """Personalized goals of one scene; with ``edits`` the user's document replaces the generated one
    after it is checked against the scene's objects. ``goal_region(members, object_index, keys)`` ->
    ``(rows, cols)`` bool goal region of a same_goal group (the routes stage's definition; used by the
    procedural feedback), or None. A ``building`` gives each floor's grid, walls, planner and regions (``grid``,
    ``walls``, ``planner`` and ``goal_region`` are then unused): a goal's feedback is made on its own floor, and
    its procedural feedback walks from the start's floor over the stairs."""
    if not objset.objects:
        raise StageError(f"scene {objset.scene}: no objects to make goals from")
    rng = np.random.default_rng(settings.seed)
    objects = sorted(objset.objects, key=lambda o: o.key)
    by_key = {o.key: o for o in objects}
    rooms = assign_rooms(objset.rooms, rng)
    groups = same_goal_groups(objects, settings.same_goal_radius_m)
    identities_by_group = personalize(objects, rooms, groups, rng)
    identities = {k: ident for ident in identities_by_group.values() for k in ident.members}
    keys = [o.key for o in objset.objects]
    if building is None:
        object_index = rasterize_polygons([np.asarray(o.footprint) for o in objset.objects], grid)
    else:
        indexes = {f: part.object_index for f, part in building.floors.items()}

    drafts = []
    for g, t in select_groups(objset, groups, settings, rng):
        o = by_key[g[0]]
        info = rooms.get(o.room or "")
        drafts.append(GoalDraft(id=g[0], name=identities[g[0]].name, type=t, cls=o.cls, room_id=o.room,
                                room_name=info.name if info else None, members=g))
    ensure_unique([d.name for d in drafts], "goal name")
    _prepare_regions([d.members for d in drafts], by_key, goal_region, object_index if building is None else None,
                     keys, building)
    if building is None:
        ctx = FeedbackContext(objects=by_key, identities=identities, rooms=rooms, goals=drafts, grid=grid,
                              walls=np.asarray(walls, dtype=bool), object_index=object_index, object_keys=keys,
                              planner=planner, start_pose=start_pose,
                              goal_region=None if goal_region is None else
                              (lambda members: goal_region(members, object_index, keys)),
                              settings=settings)
        contexts = {0: ctx}
    else:  # a floor's goals see that floor's objects, walls and regions
        contexts = {f: FeedbackContext(
            objects={k: o for k, o in by_key.items() if o.floor == f}, identities=identities, rooms=rooms,
            goals=drafts, grid=part.grid, walls=np.asarray(part.walls, bool), object_index=part.object_index,
            object_keys=keys, planner=part.planner, start_pose=start_pose,
            goal_region=(lambda members, part=part: part.goal_region(members, part.object_index, keys)),
            settings=settings, building=building.planner, start_floor=building.start_floor, floor=f)
            for f, part in building.floors.items()}
        object_index = [indexes[f] for f in sorted(indexes)]
    goals = []
    landmarks = {}
    planners = list({id(c.planner): c.planner for c in contexts.values() if hasattr(c.planner, "forget")}.values())
    for d in drafts:
        ctx = contexts[by_key[d.members[0]].floor if building is not None else 0]
        fb = {name: kind().generate(d, ctx) for name, kind in sorted(FEEDBACK_KINDS.items())}
        goals.append(GoalEntry(id=d.id, name=d.name, type=d.type, room=d.room_name, room_id=d.room_id,
                               objects=list(d.members), feedback=Feedback(**fb)))
        landmarks[d.id] = find_landmarks(d, ctx)
        for p in planners:  # the goal's fields (a floor's grid each): memory for one goal's at a time
            p.forget(d.id)
    doc = GoalsDocument(
        scene=objset.scene,
        rooms={r.id: RoomEntry(type=r.type, owners=list(r.owners), name=r.name) for r in rooms.values()},
        objects={o.key: ObjectEntry(cls=o.cls, identity=identities[o.key].name, room=o.room,
                                    position_xy=(round(o.mass_center[0], 3), round(o.mass_center[1], 3)))
                 for o in objects},
        goals=goals,
    )
    if edits is None:
        return GoalsResult(doc, landmarks, object_index)
    if edits.scene != objset.scene:
        raise InputDataError(f"edits are for scene {edits.scene!r}, not {objset.scene!r}", path=edits_path,
                             field="scene")
    check_against_objects(edits, set(by_key), set(rooms), path=edits_path)
    # geometry is the scene's; the edit may only rename/re-describe
    edited = edits.model_copy(update={"objects": {k: e.model_copy(update={"position_xy": doc.objects[k].position_xy})
                                                  for k, e in edits.objects.items()}})
    kept = {g.id: landmarks.get(g.id) or _landmarks_for(
        g, contexts[by_key[g.objects[0]].floor if building is not None else 0]) for g in edited.goals}
    return GoalsResult(edited, kept, object_index, edited=True)


def _prepare_regions(groups: list[tuple[str, ...]], by_key: dict, goal_region, object_index, keys: list[str],
                     building: Building | None) -> None:
    """Tell a ``goal_region`` that can read ahead (:meth:`GoalRegions.prepare`) every goal group it will be asked
    for, per floor in a building: it reads the mesh around them all at once."""
    if building is None:
        if hasattr(goal_region, "prepare"):
            goal_region.prepare(groups, object_index, keys)
        return
    for f, part in building.floors.items():
        if hasattr(part.goal_region, "prepare"):
            part.goal_region.prepare([g for g in groups if by_key[g[0]].floor == f], part.object_index, keys)


def _landmarks_for(goal: GoalEntry, ctx: FeedbackContext) -> list[dict]:
    o = ctx.objects[goal.objects[0]]
    draft = GoalDraft(goal.id, goal.name, goal.type, o.cls, goal.room_id, goal.room, tuple(goal.objects))
    return find_landmarks(draft, ctx)


def prune_document(doc: GoalsDocument, object_keys: set[str]) -> tuple[GoalsDocument, list[str]]:
    """Drop goals whose objects are gone (and entries naming missing objects); returns the dropped goal ids."""
    kept, dropped = [], []
    for g in doc.goals:
        if all(k in object_keys for k in g.objects):
            corr = {k: v for k, v in g.feedback.corrective.items() if k in object_keys}
            kept.append(g.model_copy(update={"feedback": g.feedback.model_copy(update={"corrective": corr})}))
        else:
            dropped.append(g.id)
    objects = {k: v for k, v in doc.objects.items() if k in object_keys}
    return doc.model_copy(update={"goals": kept, "objects": objects}), dropped


# ----------------------------------------------------------------------------- one scene (the goals stage's work)

# GT walls block line of sight from this height above the floor (skirting and floor-level clutter do not)
WALL_MIN_HEIGHT_M = 0.05
# without GT walls, occupied cells within this distance of an object footprint are the object, not a wall
OBJECT_MARGIN_M = 0.15


def load_objects(scene: str, frames: FrameStore, grid: GridSpec, p: GoalsParams, root: Path, log=print
                 ) -> tuple[ObjectSet, GoalsDocument | None, GTScene | None]:
    """``(ObjectSet, navchat goals document | None, GTScene | None)`` per ``goals.objects``; paths in ``p``
    are relative to ``root`` (the params file's folder)."""
    gt = frames.ground_truth
    kind = p.objects
    if kind == "auto":
        kind = "gt" if gt is not None else "file" if scene in p.objects_files else "navchat" if scene in p.navchat_dirs else ""
    if kind == "gt":
        if gt is None:
            raise InputDataError("no ground truth (attrs.ground_truth) to take objects from", path=frames.path,
                                 field="attrs.ground_truth", expected="a simulated scene, or goals.objects: file")
        return objects_from_gt(gt, scene), None, gt
    if kind == "file":
        if scene not in p.objects_files:
            raise ConfigError(f"goals.objects_files.{scene}: no objects file given for scene {scene!r}")
        return objects_from_file(root / p.objects_files[scene], scene), None, None
    if kind == "navchat":
        if scene not in p.navchat_dirs:
            raise ConfigError(f"goals.navchat_dirs.{scene}: no navchat folder given for scene {scene!r}")
        objset, doc = import_navchat(root / p.navchat_dirs[scene], navchat_frame(p.navchat_grid, frames, grid), scene,
                                     log=log)
        return objset, doc, None
    raise ConfigError(f"goals.objects: scene {scene!r} has no ground truth; give goals.objects_files.{scene} "
                      f"or goals.navchat_dirs.{scene}")


def wall_grid(objset: ObjectSet, recon: Recon, gt: GTScene | None, object_index: np.ndarray) -> np.ndarray:
    """``(rows, cols)`` bool cells that block line of sight: GT walls (from :data:`WALL_MIN_HEIGHT_M` up to the
    wall height), else occupied cells farther than :data:`OBJECT_MARGIN_M` from every object footprint."""
    grid = recon.grid
    if gt is not None:
        return gt.occupancy(grid, WALL_MIN_HEIGHT_M, gt.wall_height_m, objects=False)
    near_obj = ndimage.binary_dilation(object_index > 0,
                                       iterations=max(1, int(round(OBJECT_MARGIN_M / grid.cell_size_m))))
    return (recon.occupancy == OCCUPIED) & ~near_obj


def scene_building(recon: Recon, objset: ObjectSet, gt: GTScene | None, settings: RouteSettings, success_m: float,
                   frames: FrameStore, objects_path) -> tuple[Building, GoalRegions]:
    """The goals stage's view of a building (:mod:`pipeline.goals.floors`): each floor's grid, walls, footprints,
    planner and regions, the planner over every floor, the floor the recording starts on; and floor 0's regions."""
    from pipeline.nav.building import building_planner

    floors_of_objects(objset, len(recon.floors), objects_path)
    planner = building_planner(recon, settings)
    parts = {}
    for f in range(len(recon.floors)):
        fg = recon.floor(f)
        index = floor_object_index(objset, f, fg.grid)
        if gt is not None and gt.floors:
            view = gt.floor_view(f)
            walls = view.occupancy(fg.grid, WALL_MIN_HEIGHT_M, view.wall_height_m, objects=False)
        else:
            near_obj = ndimage.binary_dilation(index > 0, iterations=max(1, int(round(OBJECT_MARGIN_M /
                                                                                      fg.grid.cell_size_m))))
            walls = (fg.occupancy == OCCUPIED) & ~near_obj
        parts[f] = FloorParts(fg.grid, walls, index, planner.planners[f], GoalRegions(recon, objset, success_m, f))
    T0 = first_camera(frames)
    start_floor = int(recon.floor_of_z(T0[2, 3])) if T0 is not None else 0
    return Building(parts, planner, start_floor), parts[0].goal_region


class GoalRegions:
    """The goal regions of one scene, each computed once: ``regions(members, object_index, keys)`` -> ``(rows, cols)``
    bool region of a same_goal group (:func:`pipeline.nav.region.group_region`: navigable cells within
    ``success_m`` of a member's footprint that see its mass centre, line of sight by ray casting
    ``recon_mesh.ply`` from the recording's median camera height). The mesh is read a window around each member
    (:class:`pipeline.nav.sight.WindowedSight`), so memory follows the goals, not the floor's area; :meth:`prepare`
    reads the windows of every group about to be asked in one pass over the file.

    The goals stage plans procedural feedback into these regions and stores them in ``goals.zarr``; the routes
    stage and the evaluator read them from there, so a region is never computed twice."""

    def __init__(self, recon: Recon, objset: ObjectSet, success_m: float, floor: int = 0):
        self.recon, self.success_m, self.floor = recon, success_m, floor
        self.objects = {o.key: o for o in objset.objects}
        self._regions: dict[tuple[str, ...], np.ndarray] = {}
        self._sight: WindowedSight | None = None
        self._camera_height_m = 0.0

    @property
    def sight(self) -> WindowedSight:
        if self._sight is None:
            r = self.recon
            fg = r.floor(self.floor)
            poses = r.poses
            if len(r.floors) > 1:  # the camera's height above this floor, from the frames taken on it
                on = r.floor_of_z(poses[:, 2, 3]) == self.floor
                poses = poses[on] if on.any() else poses
            self._camera_height_m = recorded_camera_height(poses, fg.floor_z)
            self._sight = WindowedSight(r.mesh_path, floor_z=fg.floor_z, camera_height_m=self._camera_height_m,
                                        grid=fg.grid)
        return self._sight

    def prepare(self, groups, object_index: np.ndarray, keys) -> None:
        """Read the mesh around every member of ``groups`` (same_goal groups of object keys) at once."""
        keys = list(keys)
        grid = self.recon.floor(self.floor).grid if self.floor else self.recon.grid
        boxes = [sight_window(object_index == keys.index(k) + 1, grid, self.objects[k].mass_center,
                              success_m=self.success_m)
                 for members in groups if tuple(members) not in self._regions for k in members]
        boxes = [b for b in boxes if b is not None]
        if boxes:
            self.sight.prepare(boxes)

    def __call__(self, members, object_index: np.ndarray, keys) -> np.ndarray:
        members = tuple(members)
        if members not in self._regions:
            fg = self.recon.floor(self.floor) if self.floor else self.recon
            self._regions[members] = group_region(fg.navigable, object_index, list(keys), members,
                                                  self.objects, fg.grid, self.sight, success_m=self.success_m)
        return self._regions[members]

    def attrs(self) -> tuple[dict, dict]:
        """``(goal_region, sight)`` attrs of ``goals.zarr``: the definition and radius, and the line-of-sight test."""
        sight = self.sight
        # the words stored since goals.zarr format 1, which named the function where it then lived (now
        # pipeline.nav.region.group_region): changing them would change every goals digest for no change of content
        return ({"definition": "navigable cells within success_m of a member's footprint that see its mass centre "
                               "(pipeline.routes.region.group_region)", "success_m": self.success_m},
                {"method": SIGHT_METHOD, "camera_height_m": round(self._camera_height_m, 4),
                 "levels": list(SIGHT_LEVELS), "tolerance_m": sight.tolerance,
                 "own_dilation_cells": OWN_DILATION_CELLS})


def first_camera(frames: FrameStore) -> np.ndarray | None:
    """``T_world_camera`` (4, 4) of the recording's first camera with a finite pose, or None."""
    poses = frames.poses()
    ok = np.flatnonzero(np.isfinite(poses).all(axis=(1, 2)))
    return poses[ok[0]] if ok.size else None


def start_pose(frames: FrameStore, T: np.ndarray | None = None) -> tuple[float, float, float] | None:
    """``(x_m, y_m, yaw_rad)`` of the recording's first camera with a finite pose (``T`` when the caller has it,
    :func:`first_camera`), or None."""
    T = first_camera(frames) if T is None else T
    return None if T is None else (float(T[0, 3]), float(T[1, 3]), float(camera_yaw(T)))


def start_snap_m(T: np.ndarray | None, frames: FrameStore, recon: Recon, building: Building | None) -> float:
    """How far the recording's start may move onto the navigable grid (:func:`walkable_start`): the first camera's
    blind radius on its floor plus a cell (:func:`blind_radius_m`: a camera 1.25 m up with a 74 degree vertical
    field first sees the floor 1.7 m ahead), at least :data:`START_SNAP_MIN_M`. ``T``: the first camera
    (:func:`first_camera`)."""
    if T is None:
        return START_SNAP_MIN_M
    floor_z = recon.floor_z if building is None else recon.floors[building.start_floor].floor_z_m
    blind = blind_radius_m(T, frames.intrinsics, floor_z) + recon.grid.cell_size_m
    return max(START_SNAP_MIN_M, blind) if np.isfinite(blind) else START_SNAP_MIN_M


def build_scene_goals(frames: FrameStore, recon: Recon, out_path: Path, attrs: dict, *, scene: str, goals: GoalsParams,
                      task: TaskParams, root: Path, log: Callable[[str], None] = print) -> dict:
    """The goals of ``scene`` and their goal regions written to a new ``goals.zarr`` at ``out_path`` (``attrs``: its
    artifact attrs); the ``task``'s success radius cuts the regions, and its action space, stop radius and
    clearance plan the procedural feedback as the routes stage plans its episodes. Paths in ``goals`` are
    relative to ``root``. Returns the summary figures (the stage's manifest summary)."""
    t0 = time.perf_counter()
    p = goals
    grid = recon.grid
    objset, navchat_doc, gt = load_objects(scene, frames, grid, p, root, log=log)
    if objset.source == "navchat":
        check_navchat_coverage(objset, grid, recon.occupancy != UNKNOWN, p.navchat_max_outside,
                               path=p.navchat_dirs[scene], log=log)
    edits, edits_path, edits_info = navchat_doc, None, None
    if scene in p.edits:
        edits_path = root / p.edits[scene]
        edits = load_document(edits_path)
        digest = document_digest(edits)
        if digest not in edits_path.name:
            raise InputDataError(f"content digest {digest} is not in the file name; the file was changed after "
                                 f"import (import it again: zipon goals import)", path=edits_path)
        edits_info = {"path": p.edits[scene], "digest": digest}
    dropped: list[str] = []
    if edits is not None and p.edits_missing_objects == "drop":
        edits, dropped = prune_document(edits, {o.key for o in objset.objects})
        for d in dropped:
            log(f"edited goal {d} dropped: its objects no longer exist")
    settings = RouteSettings.from_config(task)
    planner = RoutePlanner(recon.navigable, grid, settings)
    object_index = rasterize_polygons([np.asarray(o.footprint) for o in objset.objects], grid)
    walls = wall_grid(objset, recon, gt, object_index)
    T0 = first_camera(frames)
    pose0 = start_pose(frames, T0)
    regions = GoalRegions(recon, objset, task.success_m)
    building = None
    start_nav = recon.navigable
    if len(recon.floors) > 1:
        objects_path = root / p.objects_files[scene] if objset.source == "file" else frames.path
        building, regions = scene_building(recon, objset, gt, settings, task.success_m, frames, objects_path)
        start_nav = building.planner.planners[building.start_floor].navigable
    snap_m = start_snap_m(T0, frames, recon, building)
    pose0, moved = walkable_start(pose0, start_nav, grid, max_m=snap_m)
    if moved:
        log(f"the recording's start lies on a cell not seen as floor; procedural feedback starts {moved:.2f} m away, "
            "on the nearest navigable cell")
    elif pose0 is not None and not grid.holds(start_nav, pose0):
        log(f"the recording's start lies more than {snap_m:.2f} m (its first camera's blind radius) from any cell "
            "seen as navigable floor: its goals get no procedural feedback")
    res = build_goals(objset, grid, walls, planner=planner, start_pose=pose0, settings=p, edits=edits,
                      edits_path=edits_path, goal_region=regions, building=building)
    keys = [o.key for o in objset.objects]
    floor_of = {o.key: o.floor for o in objset.objects}
    indexes = res.object_index if isinstance(res.object_index, list) else [res.object_index]
    if res.edited:  # the user's goals may be other groups than the generated ones: read around them too
        _prepare_regions([tuple(g.objects) for g in res.document.goals], objset.by_key(), regions, indexes[0], keys,
                         building)
    region_of = (lambda g: regions(g.objects, res.object_index, keys)) if building is None else (
        lambda g: building.floors[floor_of[g.objects[0]]].goal_region(
            g.objects, indexes[floor_of[g.objects[0]]], keys))
    region_attrs, sight_attrs = (regions if building is None else building.floors[0].goal_region).attrs()
    write_goals(out_path, document=res.document, objset=objset, landmarks=res.landmarks,
                object_index=res.object_index, grid=grid, attrs=attrs, start_pose=pose0, edits=edits_info,
                regions={g.id: region_of(g) for g in res.document.goals}, region_attrs=region_attrs,
                sight=sight_attrs,
                floors=None if building is None else [{"id": f.id, "name": f.name, "floor_z_m": f.floor_z_m}
                                                      for f in recon.floors],
                region_floors=None if building is None else [floor_of[g.objects[0]] for g in res.document.goals])
    built = res.document.goals
    types = {t: sum(g.type == t for g in built) for t in GOAL_TYPES}
    log(f"{len(built)} goals ({types['big']} big, {types['small']} small, {types['ambiguous']} ambiguous) "
        f"from {len(objset.objects)} {objset.source} objects")
    return {
        "objects": len(objset.objects), "objects_source": objset.source, "goals": len(built), **types,
        "same_goal_groups": sum(len(g.objects) > 1 for g in built),
        "with_landmarks": sum(bool(g.feedback.landmark) for g in built),
        "with_procedural": sum(g.feedback.procedural is not None for g in built),
        "edited": bool(res.edited), "dropped_edited_goals": dropped,
        "seconds": round(time.perf_counter() - t0, 3),
    }
