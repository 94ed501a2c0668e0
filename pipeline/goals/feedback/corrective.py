"""Corrective feedback: reaching another object, the agent is told that object's own identity."""

from __future__ import annotations

from pipeline.goals.feedback.base import FeedbackContext, FeedbackKind, GoalDraft, register


@register
class Corrective(FeedbackKind):
    """Keys: every same-class object outside the goal's group and every object of another goal."""

    name = "corrective"

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> dict[str, str]:
        others = {k for k, o in ctx.objects.items() if o.cls == goal.cls}
        others |= {k for g in ctx.goals for k in g.members}
        others -= set(goal.members)
        return {k: f"This is {ctx.identities[k].name}, not {goal.name}." for k in sorted(others)}
