"""``human``: the ground-truth upper bound — walks the geodesic route to the goal and asks once."""

from __future__ import annotations

from orion_eval.agents.base import Agent, register


@register
class HumanAgent(Agent):
    """Knows the goal (ground truth): FMM route to the nearest cell that sees the goal within the stop radius,
    face its mass centre, Talk."""

    name = "human"

    def run(self, m, instruction: str, goal_name: str) -> None:
        goal = m.run.user.goal  # the upper bound may look at the ground truth
        ctx = m.ctx
        geo = m.run.user.geometry
        view = ctx.viewpoints(("goal", goal.id), ctx.footprint_mask(goal.object_keys), goal.mass_center,
                              tuple(geo.z_levels[0]))
        route = ctx.view_planner.route(m.pose, view, key=("goal-view", goal.id), face_xy=goal.mass_center)
        m._follow(route)
        m.talk(f"I am at {goal_name}.")
