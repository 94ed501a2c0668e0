"""``vlmap`` / ``cf``: map-retrieval agents (VLMaps-like, ConceptFusion-like) — no exploration, no memory.

The candidates of the goal's name on the map are visited nearest first; feedback re-ranks them:
a description re-queries the map and ranks by score, landmarks rank by distance to the landmarks'
map candidates, a route is followed and the ranking restarts from the new pose.
"""

from __future__ import annotations

import numpy as np

from orion_eval.agents.base import Agent, parse_feedback, register


class MapAgent(Agent):
    which = "vlmap"

    def candidates(self, m, query: str, order: str, anchors: list) -> list[int]:
        triples = m.retrieve_map(query, self.which)
        if order == "score":
            scores = m.map_scores(query, self.which)
            return [t[0] for t in sorted(triples, key=lambda t: (-round(scores.get(t[0], 0.0), 3), t[1]))]
        if order == "landmark" and anchors:
            a = np.asarray(anchors)
            near = lambda t: float(np.min(np.hypot(*(a - m.objects[t[0]].center_xy).T)))
            return [t[0] for t in sorted(triples, key=lambda t: (round(near(t), 2), t[1]))]
        return [t[0] for t in triples]

    def run(self, m, instruction: str, goal_name: str) -> None:
        query, order, anchors = goal_name, "distance", []
        rejected: list = []
        radius = self.params.eval.reject_radius_m
        while True:
            todo = [i for i in self.candidates(m, query, order, anchors)
                    if not self.near_any(m, i, rejected, radius)]
            if not todo:
                return
            oid = todo[0]
            rejected.append(m.objects[oid].center_xy)
            if not m.goto_object(oid):
                continue
            fb = parse_feedback(m.talk(f"Is this {goal_name}?"))
            query, order, anchors = self.rerank(m, fb, query, order, anchors)
            if fb.route:
                self.follow_route(m, fb.route)
                order = "distance" if order != "score" else order

    def rerank(self, m, fb, query: str, order: str, anchors: list) -> tuple[str, str, list]:
        """Feedback that re-ranks the candidates: a description re-queries the map and ranks by score;
        landmarks rank by distance to the landmarks' map candidates. Returns ``(query, order, anchors)``."""
        if fb.description:
            query, order = fb.description, "score"
        if fb.landmarks:
            anchors = [m.objects[t[0]].center_xy for lm in fb.landmarks for t in m.retrieve_map(lm, self.which)]
            order = "landmark" if anchors else order
        return query, order, anchors


@register
class VLMapAgent(MapAgent):
    name, which, label, colour = "vlmap", "vlmap", "VLMap", "#2ca02c"


@register
class CFAgent(MapAgent):
    name, which, label, colour = "cf", "cfmap", "CF", "#9467bd"

