"""Procedural feedback: the route in words from the recording's start pose (see pipeline.routes).

With the scene's goal regions (:class:`pipeline.goals.build.GoalRegions`: navigable cells within the
success distance that see the goal's mass centre, on the reconstructed mesh; stored in goals.zarr, where
the routes stage reads them) the route is planned exactly as the routes stage plans its episodes (:func:`pipeline.nav.region.route_to_goal`:
into the region's route target, else the region; facing the nearest member's mass centre), so the
text here and in ``routes.zarr`` / the evaluator's user describe the same goal. Without regions
(no reconstruction mesh) it ends within the planner's stop radius of the footprint.
"""

from __future__ import annotations

import numpy as np

from pipeline.goals.feedback.base import FeedbackContext, FeedbackKind, GoalDraft, register
from pipeline.nav.region import GoalTargets, route_to_goal


@register
class Procedural(FeedbackKind):
    """``None`` when there is no navigable grid, no start pose, the goal cannot be reached, or the start
    already lies in the goal (no route parts)."""

    name = "procedural"

    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> str | None:
        if ctx.planner is None or ctx.start_pose is None:
            return None
        footprint = ctx.footprint_mask(goal.members)
        if ctx.goal_region is not None:
            centres = np.array([ctx.objects[k].mass_center for k in goal.members], np.float64).reshape(-1, 2)
            targets = GoalTargets.of(ctx.goal_region(goal.members), footprint, ctx.planner.grid,
                                     stop_radius_m=ctx.planner.settings.stop_radius_m)
            route = route_to_goal(ctx.planner, ctx.start_pose, targets, key=goal.id, face_xy=centres)
        else:
            face = np.asarray(ctx.objects[goal.members[0]].mass_center)
            route = ctx.planner.route(ctx.start_pose, footprint, key=goal.id, face_xy=face)
        # a start already in the region (or a route of turns under 45 deg) has nothing to say: None
        return None if route is None or not route.parts else route.text
