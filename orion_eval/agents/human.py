"""``human``: the ground-truth upper bound — walks the geodesic route to the goal and asks once."""

from __future__ import annotations

import numpy as np

from orion_eval.agents.base import Agent


class HumanAgent(Agent):
    """Knows the goal (ground truth): FMM route into the goal region the routes stage stored (within the
    success distance, mass centre in line of sight), face the nearest member's mass centre, Talk. In a building it
    first climbs the stairs nearest it to the goal's floor."""

    name, label, colour, upper_bound = "human", "Human (GT route)", "#7f7f7f", True

    def run(self, m, instruction: str, goal_name: str) -> None:
        goal = m.run.user.goal  # the upper bound may look at the ground truth
        ctx = m.ctx
        centres = np.array([ctx.scene.goals.objects[k].mass_center for k in goal.object_keys], np.float64)
        if m.floor != goal.floor:  # a building: over the nearest stairs to the goal's floor first
            m.take_stairs(goal.floor)
        # into the routes stage's goal region (pipeline.nav.region), planned as the routes stage plans
        route = ctx.route_to_goal(m.here.view_planner, m.pose, goal, key="human", face_xy=centres)
        m._follow(route)
        m.talk(f"I am at {goal_name}.")
