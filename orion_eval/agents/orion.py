"""``orion``: map retrieval + exploration + detection + memory, as ORION composes its modules.

Memory first (a positive hit for the goal's name), then map candidates (skipping places rejected
or remembered as negative), each double-checked with the ego-view detector before asking (a failed
check defers the candidate), then frontier search with detection when the map has nothing left.
Corrective feedback paints the found object's identity as positive and the goal as negative.
"""

from __future__ import annotations

from orion_eval.agents.base import parse_feedback, register
from orion_eval.agents.maps import MapAgent


@register
class OrionAgent(MapAgent):
    name, label, colour = "orion", "ORION", "#d62728"
    persistent_memory = True  # the memory is carried across the goals of a scene (evaluate_scene)

    def __init__(self, params):
        super().__init__(params)
        self.which = params.eval.orion_map

    def run(self, m, instruction: str, goal_name: str) -> None:
        query, order, anchors = goal_name, "distance", []
        rejected: list = []
        deferred: set[int] = set()
        radius = self.params.eval.reject_radius_m
        skip = lambda i: self.near_any(m, i, rejected, radius) or i in negatives
        while True:
            positives, negatives = m.retrieve_memory(goal_name)
            negatives = set(negatives)
            todo = [t[0] for t in positives if not skip(t[0])]
            todo += [i for i in self.candidates(m, query, order, anchors) if not skip(i) and i not in todo]
            todo = [i for i in todo if i not in deferred] + [i for i in todo if i in deferred]
            if todo:
                oid = todo[0]
                if not m.goto_object(oid):
                    rejected.append(m.objects[oid].center_xy)
                    continue
                if oid not in deferred and not m.double_check(oid):
                    deferred.add(oid)
                    continue
            else:
                oid = m.search_object(query, skip=skip)
                if oid is None:
                    return
                m.goto_object(oid)
            rejected.append(m.objects[oid].center_xy)
            fb = parse_feedback(m.talk(f"Is this {goal_name}?"))
            m.update_memory(oid, fb.corrected_as, goal_name)
            query, order, anchors = self.rerank(m, fb, query, order, anchors)
            if fb.route:
                self.follow_route(m, fb.route)
