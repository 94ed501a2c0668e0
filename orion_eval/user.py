"""The simulated user: deterministic per seed, template-based, given the goal's FB and the agent's state.

Settings (``eval.feedback``), each one entry of :data:`FEEDBACK_SETTINGS` (no interaction, yes/no, one per
feedback kind of :data:`pipeline.goals.feedback.FEEDBACK_KINDS`, mixed):

- ``none``: no interaction — the first Talk ends the episode (success is judged there);
- ``yesno``: "Yes, this is X." / "No.";
- one per feedback kind (``corrective``, ``descriptive``, ``landmark``, ``procedural``): "No. " and what the kind's
  :meth:`~pipeline.goals.feedback.base.FeedbackKind.say` says at the agent's CURRENT pose, from the goal's stored
  feedback (each kind's module gives its phrases, and how an agent reads them back); "No." when the kind has nothing
  to say there (the agent looks at no object the corrective FB names, the goal has no landmark, ...). Procedural
  directions are planned with the routes planner and spoken as a person gives them: distances misjudged (a seeded
  factor ``exp(N(0, SPEECH_NOISE))``) and said in whole metres, turns only as left / right / around: approximate,
  "not precise" as the paper says. Each misjudgement is drawn for what is judged — the episode's key, the place the
  user is asked from, the distance's place in the reply — never in the order of the episode's calls, so two settings
  of one (seed, goal) asked at the same place say the same route (common random numbers: settings differ only in
  which kinds are said);
- ``mixed``: every kind available at that moment in one reply (corrective, descriptive, landmark,
  procedural, in that order), as the paper's user-LLM received all of them at once.

"The object the agent looks at" is the object whose mass centre is in the ego view and in line of
sight, nearest first (within 2.5 m), by the same geometry as the success rule.

In a building the user knows the floors: success is judged on the goal's floor only (elsewhere the episode has not
arrived: distance unknown, null in the results); only objects on the agent's floor can be looked at; directions
from another floor are planned over the stairs (:meth:`SceneContext.route_across`, as the goals stage plans them)
and said with the stairs ("Go up the stairs. At the top, follow this route: ..."); and the landmark kind says which
floor the goal is on when the agent is on another ("It is upstairs."): :meth:`SimulatedUser.floor_words`.
"""

from __future__ import annotations

import math

import numpy as np

from orion_eval.world import floor_of
from pipeline.goals.feedback import FEEDBACK_KINDS, feedback_kind
from pipeline.goals.feedback.base import floor_words

FEEDBACK_KIND_NAMES = tuple(sorted(FEEDBACK_KINDS))  # the goals' feedback kinds (their registry's names)
FEEDBACK_SETTINGS = ("none", "yesno", *FEEDBACK_KIND_NAMES, "mixed")
#: the setting of episodes a person answered (``zipon annotate``, Play): stored, never simulated, reported as their own
HUMAN_FEEDBACK = "human"
LOOK_RANGE_M = 2.5
#: sigma of the log-normal factor a spoken distance is misjudged by (modelling choice: about a fifth either way)
SPEECH_NOISE = 0.2


class SimulatedUser:
    """One episode's user (see the module docstring). ``goal`` is a :class:`~pipeline.goals.store.GoalView`."""

    def __init__(self, ctx, goal, setting: str, rng: np.random.Generator):
        if setting not in FEEDBACK_SETTINGS:
            raise ValueError(f"unknown feedback setting {setting!r}; choose from {FEEDBACK_SETTINGS}")
        self.ctx, self.goal, self.setting = ctx, goal, setting
        # one draw from the episode's generator keys every misjudgement (say_metres): the user's words are a
        # function of (episode, place asked from, what is judged), the same in every setting given that rng
        self.key = int(rng.integers(2**63))
        self.geometry = goal_geometry(ctx, goal.object_keys)
        self.rule = ctx.level(goal.floor).success  # the success rule of the goal's floor

    def instruction(self) -> str:
        return f"Please go to {self.goal.name}."

    def judge(self, pose) -> dict:
        """``{success, distance_m, bearing_deg, visible}`` at ``pose``; on another floor than the goal's, no success
        and an infinite distance (the goal is not on the floor the agent stands on)."""
        if floor_of(pose) != self.goal.floor:
            return {"success": False, "distance_m": math.inf, "bearing_deg": 180.0, "visible": False}
        return self.rule.evaluate(pose, self.geometry)

    def looked_at(self, pose, keys) -> str | None:
        """The key among ``keys`` (the objects the corrective FB names) of the object the agent is looking at (on
        the agent's floor)."""
        best, best_d = None, np.inf
        objects, floor = self.ctx.scene.goals.objects, floor_of(pose)
        rule = self.ctx.level(floor).success
        for key in keys:
            if objects[key].floor != floor:
                continue
            r = rule.evaluate(pose, goal_geometry(self.ctx, (key,)))
            if r["visible"] and abs(r["bearing_deg"]) <= self.ctx.params.task.hfov_deg / 2 and \
                    r["distance_m"] <= LOOK_RANGE_M and r["distance_m"] < best_d:
                best, best_d = key, r["distance_m"]
        return best

    def say_metres(self, metres: float, where: tuple[int, ...]) -> str:
        """A distance as a person says it: misjudged by a factor drawn for ``where`` (the place asked from and the
        distance's place in the reply: the same ``where`` is misjudged the same), in whole metres (at least 1)."""
        factor = float(np.exp(np.random.default_rng([self.key, *where]).normal(0.0, SPEECH_NOISE)))
        v = max(1, int(round(metres * factor)))
        return f"{v} meter" if v == 1 else f"{v} meters"

    def route_from(self, pose):
        """The route from ``pose`` into the routes stage's goal region (it never ends behind a wall), facing the
        goal's mass centre; None when the goal cannot be reached from ``pose``. From another floor, the route over
        the stairs (a :class:`~pipeline.nav.building.FloorRoute`)."""
        g = self.goal
        if floor_of(pose) != g.floor:
            return self.ctx.route_across(pose, g, key="user", face_xy=g.mass_center)
        return self.ctx.route_to_goal(self.ctx.level(g.floor).user_planner, pose, g, key="user",
                                      face_xy=g.mass_center)

    def room_at(self, pose) -> str | None:
        return self.ctx.room_at(pose)

    def floor_words(self, pose) -> str | None:
        """Where the goal's floor is from the agent's, as a person says it ("upstairs", "2 floors down"); None on
        the goal's floor."""
        return floor_words(self.goal.floor - floor_of(pose))

    def place_key(self, pose) -> tuple[int, ...]:
        """The place asked from as non-negative seed words."""
        return tuple(v % 2**32 for v in self.ctx.pose_key(pose))

    def procedural(self, pose) -> str | None:
        """Directions from ``pose`` (the procedural kind's :meth:`~pipeline.goals.feedback.base.FeedbackKind.say`)."""
        return self.feedback("procedural", pose)

    def feedback(self, kind: str, pose) -> str | None:
        """What the user says of feedback ``kind`` at ``pose`` (None: nothing there); a kind the registry lacks is a
        ConfigError naming the registered kinds."""
        return feedback_kind(kind).say(self.goal.feedback.get(kind), self, pose)

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
            texts = {k: self.feedback(k, pose) for k in FEEDBACK_KIND_NAMES}  # procedural last: a route ends a reply
            avail = [k for k in FEEDBACK_KIND_NAMES if texts[k]]
            if not avail:
                return False, "No.", "no"
            return False, "No. " + " ".join(texts[k] for k in avail), "+".join(avail)
        text = self.feedback(self.setting, pose)
        return (False, f"No. {text}", self.setting) if text else (False, "No.", "no")


def goal_geometry(ctx, keys: tuple[str, ...]):
    """Success-rule geometry of a group of object keys (cached on the scene context)."""
    cache = ctx.__dict__.setdefault("_goal_geometry", {})
    if keys not in cache:
        goals = ctx.scene.goals
        objs = [goals.objects[k] for k in keys]
        cache[keys] = ctx.success.geometry([np.asarray(o.footprint) for o in objs], [o.mass_center for o in objs],
                                           [o.z_range for o in objs], ctx.footprint_mask(keys))
    return cache[keys]
