"""Descriptive feedback: the goal's appearance, state and function (or human text when given).

Said as stored: "It is a red chair made of wood. It stands on the floor and is about 0.9 meters tall. ..."; read back
as ``description`` ("red chair made of wood": what the first "It is a/an ..." sentence says the goal looks like).
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from pydantic import Field

from pipeline.goals.feedback.base import (FeedbackContext, FeedbackKind, GoalDraft, appearance, object_phrase,
                                          register)
from pipeline.goals.feedback.landmark import polygon_distance, relation

SAID = re.compile(r"It is (?:a|an) (.+?)\.")

FUNCTIONS = {
    "bed": "people sleep in it", "chair": "it is for sitting at", "couch": "people sit and relax on it",
    "sofa": "people sit and relax on it", "table": "people eat or work at it", "desk": "people work at it",
    "tv": "it is for watching shows", "lamp": "it gives light", "plant": "it is a decoration that needs water",
    "toilet": "it is a plumbing fixture", "sink": "it is for washing hands", "refrigerator": "it keeps food cold",
    "cabinet": "it stores things behind doors", "shelf": "it holds books and things", "nightstand":
    "it is a small table beside a bed", "dresser": "it stores clothes in drawers", "computer": "it is for work "
    "and games", "oven": "it is for cooking", "bathtub": "it is for bathing", "wardrobe": "it stores clothes",
}


@register
class Descriptive(FeedbackKind):
    name = "descriptive"
    field = (str, Field("", description="appearance, state, function"))
    new_goal = "It is a {class}."
    parsed = {"description": lambda: None}

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> str:
        obj = ctx.objects[goal.members[0]]
        if obj.description:
            return " ".join(s.strip().rstrip(".") + "." for s in obj.description if s.strip())
        look = appearance(obj)
        article = "an" if look[:1].lower() in "aeiou" else "a"
        out = [f"It is {article} {look}."]
        height = obj.z_range[1]
        if obj.z_range[0] > 0.05:
            gpoly = np.asarray(obj.footprint)
            support = [k for k, o in ctx.objects.items() if k not in goal.members
                       and polygon_distance(gpoly, np.asarray(o.footprint)) == 0.0 and relation(obj, o, 0.0) == "on"]
            if support:
                out.append(f"It sits on {object_phrase(support[0], ctx)}.")
        else:
            out.append(f"It stands on the floor and is about {height:.1f} meters tall.")
        if obj.cls in FUNCTIONS:
            fn = FUNCTIONS[obj.cls]
            out.append(fn[0].upper() + fn[1:] + ".")
        if len(goal.members) > 1:
            out.append(f"There are {len(goal.members)} of them side by side; any one of them will do.")
        return " ".join(out)

    def parse(self, reply: str) -> dict[str, Any]:
        m = SAID.search(reply)
        return {"description": m.group(1)} if m else {}
