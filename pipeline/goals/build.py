"""Objects -> personalized goals with feedback: selection, names, FB, and applying user edits.

One pure function, :func:`build_goals`, from plain inputs (objects, grid, wall/navigable arrays, a
start pose, settings) to a :class:`~pipeline.goals.schema.GoalsDocument` plus the structured
landmarks; the goals stage only reads artifacts and writes the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.errors import InputDataError, StageError
from pipeline.geometry import GridSpec
from pipeline.goals.feedback import FEEDBACK_KINDS, FeedbackContext, GoalDraft
from pipeline.goals.feedback.landmark import find_landmarks
from pipeline.goals.naming import assign_rooms, ensure_unique, personalize, same_goal_groups
from pipeline.goals.objects import ObjectSet, rasterize_polygons
from pipeline.goals.schema import (Feedback, GoalEntry, GoalsDocument, ObjectEntry, RoomEntry,
                                   check_against_objects)

GOAL_TYPES = ("big", "small", "ambiguous")


@dataclass(frozen=True)
class GoalSettings:
    """The parts of GoalsParams the algorithm reads (plain values, see pipeline.config.GoalsParams)."""

    seed: int = 0
    max_goals: int = 12
    mix: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)  # big, small, ambiguous
    same_goal_radius_m: float = 2.0
    landmark_radius_m: float = 1.0
    max_landmarks: int = 3
    landmark_min_area_m2: float = 0.1
    exclude_classes: tuple[str, ...] = ()


@dataclass
class GoalsResult:
    document: GoalsDocument
    landmarks: dict[str, list[dict]]  # goal id -> [{object, relation, distance_m}]
    object_index: np.ndarray  # (rows, cols) int32, 1 + index into objects.objects, 0 none
    edited: bool = False


def group_type(cls_groups: int, size: str) -> str:
    """ambiguous when the class has other distinguishable instances in the scene, else its size."""
    return "ambiguous" if cls_groups > 1 else size


def select_groups(objset: ObjectSet, groups: list[tuple[str, ...]], s: GoalSettings, rng: np.random.Generator
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
                start_pose: tuple[float, float, float] | None = None, settings: GoalSettings = GoalSettings(),
                edits: GoalsDocument | None = None, edits_path=None, goal_region=None) -> GoalsResult:
    """Personalized goals of one scene; with ``edits`` the user's document replaces the generated one
    after it is checked against the scene's objects. ``goal_region(members, object_index, keys)`` ->
    ``(rows, cols)`` bool goal region of a same_goal group (the routes stage's definition; used by the
    procedural feedback), or None."""
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
    object_index = rasterize_polygons([np.asarray(o.footprint) for o in objset.objects], grid)

    drafts = []
    for g, t in select_groups(objset, groups, settings, rng):
        o = by_key[g[0]]
        info = rooms.get(o.room or "")
        drafts.append(GoalDraft(id=g[0], name=identities[g[0]].name, type=t, cls=o.cls, room_id=o.room,
                                room_name=info.name if info else None, members=g))
    ensure_unique([d.name for d in drafts], "goal name")
    ctx = FeedbackContext(objects=by_key, identities=identities, rooms=rooms, goals=drafts, grid=grid,
                          walls=np.asarray(walls, dtype=bool), object_index=object_index, object_keys=keys,
                          planner=planner, start_pose=start_pose,
                          goal_region=None if goal_region is None else
                          (lambda members: goal_region(members, object_index, keys)),
                          settings={"landmark_radius_m": settings.landmark_radius_m,
                                    "max_landmarks": settings.max_landmarks,
                                    "landmark_min_area_m2": settings.landmark_min_area_m2})
    goals = []
    landmarks = {}
    for d in drafts:
        fb = {name: kind().generate(d, ctx) for name, kind in sorted(FEEDBACK_KINDS.items())}
        goals.append(GoalEntry(id=d.id, name=d.name, type=d.type, room=d.room_name, room_id=d.room_id,
                               objects=list(d.members), feedback=Feedback(**fb)))
        landmarks[d.id] = find_landmarks(d, ctx)
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
    kept = {g.id: landmarks.get(g.id) or _landmarks_for(g, ctx) for g in edited.goals}
    return GoalsResult(edited, kept, object_index, edited=True)


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
