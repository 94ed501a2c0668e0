"""``cow``: CLIP-on-Wheels-like — frontier exploration plus ego-view detection, no map, no memory."""

from __future__ import annotations

from orion_eval.agents.base import Agent, parse_feedback, register


@register
class CowAgent(Agent):
    """Search (spin, then frontiers) with detection; after a "No" the place is skipped; a description
    sharpens the detection query and a route is followed."""

    name, label, colour = "cow", "CoW", "#ff7f0e"

    def run(self, m, instruction: str, goal_name: str) -> None:
        query = goal_name
        rejected: list = []
        radius = self.params.eval.reject_radius_m
        while True:
            oid = m.search_object(query, skip=lambda i: self.near_any(m, i, rejected, radius))
            if oid is None:
                return
            m.goto_object(oid)
            fb = parse_feedback(m.talk(f"Is this {goal_name}?"))
            rejected.append(m.objects[oid].center_xy)
            if fb.description:
                query = fb.description
            if fb.route:
                self.follow_route(m, fb.route)
