"""The simulated user: deterministic per seed, template-based, given the goal's FB and the agent's state.

Settings (``eval.feedback``), each one entry of :data:`FEEDBACK_SETTINGS` (no interaction, yes/no, one per
feedback kind of :data:`pipeline.goals.feedback.FEEDBACK_KINDS`, mixed):

- ``none``: no interaction — the first Talk ends the episode (success is judged there);
- ``yesno``: "Yes, this is X." / "No.";
- ``corrective``: "No. This is Bob's computer, not Alice's computer." when the agent looks at an
  object the goal's corrective FB names (else "No.");
- ``descriptive``: "No. It is a red chair made of wood. ..." (the goal's descriptive FB);
- ``landmark``: "No. It is next to Alice's bed." (landmark FB; "No." when the goal has none);
- ``procedural``: "No. Follow this route: turn left, go forward 5 meters." computed from the agent's
  CURRENT pose with the routes planner, sent under navchat's rule (goal in another room, at most
  3 parts; else "No.");
- ``mixed``: each turn one of the kinds available at that moment, drawn with the episode's seed.

"The object the agent looks at" is the object whose mass centre is in the ego view and in line of
sight, nearest first (within 2.5 m), by the same geometry as the success rule.
"""

from __future__ import annotations

import numpy as np

from pipeline.goals.feedback import FEEDBACK_KINDS
from pipeline.routes.actions import procedural_allowed

FEEDBACK_KIND_NAMES = tuple(sorted(FEEDBACK_KINDS))  # the goals' feedback kinds (their registry's names)
FEEDBACK_SETTINGS = ("none", "yesno", *FEEDBACK_KIND_NAMES, "mixed")
LOOK_RANGE_M = 2.5


class SimulatedUser:
    """One episode's user (see the module docstring). ``goal`` is a :class:`~pipeline.goals.store.GoalView`."""

    def __init__(self, ctx, goal, setting: str, rng: np.random.Generator):
        if setting not in FEEDBACK_SETTINGS:
            raise ValueError(f"unknown feedback setting {setting!r}; choose from {FEEDBACK_SETTINGS}")
        self.ctx, self.goal, self.setting, self.rng = ctx, goal, setting, rng
        self.geometry = goal_geometry(ctx, goal.object_keys)

    def instruction(self) -> str:
        return f"Please go to {self.goal.name}."

    def judge(self, pose) -> dict:
        return self.ctx.success.evaluate(pose, self.geometry)

    def looked_at(self, pose) -> str | None:
        """Key of the (non-goal) object the agent is looking at, among those the corrective FB names."""
        best, best_d = None, np.inf
        for key in sorted(self.goal.feedback.get("corrective") or {}):
            r = self.ctx.success.evaluate(pose, goal_geometry(self.ctx, (key,)))
            if r["visible"] and abs(r["bearing_deg"]) <= self.ctx.params.task.hfov_deg / 2 and \
                    r["distance_m"] <= LOOK_RANGE_M and r["distance_m"] < best_d:
                best, best_d = key, r["distance_m"]
        return best

    def procedural(self, pose) -> str | None:
        """The route in words from ``pose`` when navchat's rule allows sending it, else None."""
        ctx, g = self.ctx, self.goal
        # into the routes stage's goal region: the route never ends behind a wall
        route = ctx.route_to_goal(ctx.user_planner, pose, g, key="user", face_xy=g.mass_center)
        if route is None:
            return None
        if not procedural_allowed(route.parts, ctx.arts.room_at(pose[:2]), g.room_id):
            return None
        return route.text

    def feedback(self, kind: str, pose) -> str | None:
        fb = self.goal.feedback
        if kind == "corrective":
            key = self.looked_at(pose)
            return (fb.get("corrective") or {}).get(key) if key else None
        if kind == "descriptive":
            return fb.get("descriptive") or None
        if kind == "landmark":
            return fb.get("landmark") or None
        if kind == "procedural":
            text = self.procedural(pose)
            return f"Follow this route: {text}." if text else None
        return None

    llm = None  # an orion_eval.llm.LLMUser phrasing the replies (eval.llm.roles 'user' / 'both'); None = templates

    def respond(self, pose, question: str = "") -> tuple[bool, str, str]:
        """``(success, reply, kind)`` to the agent's Talk at ``pose`` (success is always judged geometrically)."""
        if self.llm is not None and self.setting != "none":
            ok = bool(self.judge(pose)["success"])
            return ok, self.llm.respond(question, ok), "llm"
        if self.judge(pose)["success"]:
            return True, f"Yes, this is {self.goal.name}.", "yes"
        if self.setting == "none":
            return False, "", "none"
        if self.setting == "yesno":
            return False, "No.", "no"
        if self.setting == "mixed":
            kinds = FEEDBACK_KIND_NAMES
            texts = {k: self.feedback(k, pose) for k in kinds}
            avail = [k for k in kinds if texts[k]]
            if not avail:
                return False, "No.", "no"
            k = avail[int(self.rng.integers(len(avail)))]
            return False, f"No. {texts[k]}", k
        text = self.feedback(self.setting, pose)
        return (False, f"No. {text}", self.setting) if text else (False, "No.", "no")


def goal_geometry(ctx, keys: tuple[str, ...]):
    """Success-rule geometry of a group of object keys (cached on the scene context)."""
    cache = ctx.__dict__.setdefault("_goal_geometry", {})
    if keys not in cache:
        goals = ctx.arts.goals
        objs = [goals.objects[k] for k in keys]
        cache[keys] = ctx.success.geometry([np.asarray(o.footprint) for o in objs], [o.mass_center for o in objs],
                                           [o.z_range for o in objs], ctx.footprint_mask(keys))
    return cache[keys]
