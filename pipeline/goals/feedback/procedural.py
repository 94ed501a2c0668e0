"""Procedural feedback: the route in words from the recording's start pose (see pipeline.routes)."""

from __future__ import annotations

import numpy as np

from pipeline.goals.feedback.base import FeedbackContext, FeedbackKind, GoalDraft, register


@register
class Procedural(FeedbackKind):
    """``None`` when there is no navigable grid, no start pose, or the goal cannot be reached."""

    name = "procedural"

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> str | None:
        if ctx.planner is None or ctx.start_pose is None:
            return None
        face = np.asarray(ctx.objects[goal.members[0]].mass_center)
        route = ctx.planner.route(ctx.start_pose, ctx.footprint_mask(goal.members), key=goal.id, face_xy=face)
        return None if route is None else route.text
