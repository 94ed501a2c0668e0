"""Corrective feedback: reaching another object, the agent is told that object's own identity.

Said: "This is Bob's chair, not Alice's chair." when the agent looks at one of the objects the goal's corrective
feedback names (nothing otherwise); read back as ``corrected_as`` ("Bob's chair": what the agent found instead).
"""

from __future__ import annotations

import re
from typing import Any

from pydantic import Field

from pipeline.goals.feedback.base import FeedbackContext, FeedbackKind, GoalDraft, Speaker, register

SAID = re.compile(r"This is (.+?), not (.+?)\.(\s|$)")


@register
class Corrective(FeedbackKind):
    """Keys: every same-class object outside the goal's group and every object of another goal."""

    name = "corrective"
    field = (dict[str, str], Field(default_factory=dict, description="object key -> what the user says there"))
    form = "key_lines"
    parsed = {"corrected_as": lambda: None}

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> dict[str, str]:
        others = {k for k, o in ctx.objects.items() if o.cls == goal.cls}
        others |= {k for g in ctx.goals for k in g.members}
        others -= set(goal.members)
        return {k: f"This is {ctx.identities[k].name}, not {goal.name}." for k in sorted(others)}

    def say(self, value: dict[str, str], user: Speaker, pose) -> str | None:
        key = user.looked_at(pose, sorted(value or {}))
        return (value or {}).get(key) if key else None

    def parse(self, reply: str) -> dict[str, Any]:
        m = SAID.search(reply)
        return {"corrected_as": m.group(1)} if m else {}
