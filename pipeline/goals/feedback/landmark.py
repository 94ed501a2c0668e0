"""Landmark feedback: salient objects within a radius of the goal and in line of sight, with
spatial relation words (on, under, next to, near); the easy ones to find first.

The paper's landmarks are "common and salient objects near the current goal object" that "are easily
identifiable in the room", so the user points each one out by what a robot can find it by (:func:`landmark_phrase`):
its class when the scene has one of it ("the fridge"), else its colour and material when they tell it from the
others of its class ("the white nightstand made of wood"), else its identity ("Alice's shelf": a robot that finds
shelves still has to tell which). The landmarks come in that order, each group nearest first.

Said as stored: "It is on the desk, next to Kate's chair and near Kate's shelf."; read back as ``landmarks`` (the
phrases without their relation words: ["the desk", "Kate's chair", "Kate's shelf"]). In a building, to an agent on
another floor than the goal's, the user first says which floor ("It is upstairs. It is next to the bed."), read back
as ``floor_offset`` (floors up, negative down: 1)."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from pydantic import Field

from pipeline.goals.feedback.base import (FLOOR_WORDS, FeedbackContext, FeedbackKind, GoalDraft, Speaker, appearance,
                                          class_is_unique, object_phrase, read_floor_words, register)
from pipeline.goals.objects import ObjectRecord
from pipeline.nav.fmm import segment_free

#: the spatial relation words, as :func:`relation` says them and :meth:`Landmark.parse` strips them
RELATIONS = ("next to", "near", "on", "under")
SAID = re.compile(r"It is ((?:next to|near|on|under) .+?)\.(\s|$)")
FLOOR_SAID = re.compile(rf"It is {FLOOR_WORDS}\.")


def polygon_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two polygons ``(N,2)``, ``(M,2)`` (0 when they overlap)."""
    import cv2

    ca, cb = a.astype(np.float32).reshape(-1, 1, 2), b.astype(np.float32).reshape(-1, 1, 2)
    da = [cv2.pointPolygonTest(cb, (float(x), float(y)), True) for x, y in a]
    db = [cv2.pointPolygonTest(ca, (float(x), float(y)), True) for x, y in b]
    if max(da + db) >= 0:
        return 0.0
    # vertex-to-edge distances both ways give the exact distance between disjoint polygons
    return float(min(-max(da), -max(db)))


def relation(goal: ObjectRecord, other: ObjectRecord, distance_m: float, next_to_m: float = 0.5) -> str:
    """The spatial relation of ``goal`` to ``other``: 'on', 'under', 'next to' or 'near'."""
    if distance_m <= 1e-6:
        if goal.z_range[0] >= other.z_range[1] - 0.05:
            return "on"
        if other.z_range[0] >= goal.z_range[1] - 0.05:
            return "under"
    return "next to" if distance_m <= next_to_m else "near"


def line_of_sight(walls: np.ndarray, grid, a_xy: np.ndarray, b_xy: np.ndarray) -> bool:
    """No wall cell on the straight segment between two world points."""
    x0, y1 = grid.origin_xy
    to_rc = lambda p: np.array([(y1 - p[1]) / grid.cell_size_m - 0.5, (p[0] - x0) / grid.cell_size_m - 0.5])
    return bool(segment_free(~walls, to_rc(a_xy), to_rc(b_xy))[0])


def find_landmarks(goal: GoalDraft, ctx: FeedbackContext) -> list[dict]:
    """Landmark records ``{object, relation, distance_m}``, at most ``max_landmarks``: those named by their class
    alone first (:func:`~pipeline.goals.feedback.base.class_is_unique`), then the others, each nearest first."""
    radius = ctx.settings.landmark_radius_m
    limit = ctx.settings.max_landmarks
    min_area = ctx.settings.landmark_min_area_m2
    found: dict[str, dict] = {}
    for mk in goal.members:
        g = ctx.objects[mk]
        gpoly = np.asarray(g.footprint)
        for k, o in ctx.objects.items():
            if k in goal.members or o.cls == goal.cls:
                continue
            if o.size != "big" and o.area_m2 < min_area:
                continue  # not salient
            d = polygon_distance(gpoly, np.asarray(o.footprint))
            if d > radius:
                continue
            if not line_of_sight(ctx.walls, ctx.grid, np.asarray(g.mass_center), np.asarray(o.mass_center)):
                continue
            rel = relation(g, o, d)
            if k not in found or d < found[k]["distance_m"]:
                found[k] = {"object": k, "relation": rel, "distance_m": round(d, 3)}
    return sorted(found.values(), key=lambda r: (not class_is_unique(r["object"], ctx),
                                                 not looks_unique(r["object"], ctx), r["distance_m"],
                                                 r["object"]))[:limit]


def looks_unique(key: str, ctx: FeedbackContext) -> bool:
    """Whether the object's colour and material tell it from every other object of its class (a pair counts once)."""
    o = ctx.objects[key]
    if not (o.color_name and o.material):
        return False
    own = set(ctx.identities[key].members)
    return not any(q.cls == o.cls and k not in own and (q.color_name, q.material) == (o.color_name, o.material)
                   for k, q in ctx.objects.items())


def landmark_phrase(key: str, ctx: FeedbackContext) -> str:
    """How the user points a landmark out so that it can be found: by its class when the scene has one ("the
    fridge"), else by what it looks like when that tells it apart ("the white nightstand made of wood"), else by
    its identity ("Alice's shelf")."""
    o = ctx.objects[key]
    if class_is_unique(key, ctx):
        return f"the {o.cls}"
    if looks_unique(key, ctx):
        return f"the {appearance(o)}"
    return object_phrase(key, ctx)


def _join(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


@register
class Landmark(FeedbackKind):
    name = "landmark"
    field = (str, Field("", description="salient nearby objects with relation words"))
    parsed = {"landmarks": list, "floor_offset": int}

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> str:
        marks = find_landmarks(goal, ctx)
        if not marks:
            return ""
        # the members of a pair share one name: said once
        phrases = list(dict.fromkeys(f"{m['relation']} {landmark_phrase(m['object'], ctx)}" for m in marks))
        return f"It is {_join(phrases)}."

    def say(self, value: str, user: Speaker, pose) -> str | None:
        """The stored landmarks; to an agent on another floor than the goal's, which floor first ("It is
        upstairs.")."""
        where = getattr(user, "floor_words", lambda pose: None)(pose)
        if not where:
            return value or None
        return f"It is {where}." + (f" {value}" if value else "")

    def parse(self, reply: str) -> dict[str, Any]:
        found: dict[str, Any] = {}
        floor = FLOOR_SAID.search(reply)
        if floor:
            found["floor_offset"] = read_floor_words(floor.group(1))
        m = SAID.search(reply)
        if not m:
            return found
        rel = "|".join(re.escape(r) for r in RELATIONS)
        pieces = (re.sub(rf"^({rel})\s+", "", p.strip()) for p in re.split(r",\s*|\s+and\s+", m.group(1)))
        return {**found, "landmarks": [p for p in pieces if p]}
