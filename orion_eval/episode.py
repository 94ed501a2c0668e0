"""One episode: tau = (scene, goal, p0), an agent, a simulated user, and the log of what happened.

The episode ends on success (the user confirms at a Talk), after ``eval.max_talk_turns`` Talk turns,
at the first Talk when the setting is ``none``, after ``eval.max_steps`` movement actions, or when the
agent gives up. Metrics per episode (ANCHORS.md): S in {0, 1}; SPL = S * l / max(a, l) with l the
geodesic reference length and a the travelled length; SIT = S / I with I >= 1 the number of Talk turns.

In a building an episode starts on its start floor (routes.zarr's ``start_floor``), ``l`` is the routes stage's
geodesic distance through the stairs, and its result says ``start_floor``, ``goal_floor`` and ``cross_floor`` (the
goal on another floor than the start), with the floor of every logged pose (``log.floors``); a single-floor scene's
results have none of these keys, as before buildings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from orion_eval.agents.base import run_agent
from orion_eval.modules import Modules
from orion_eval.user import SimulatedUser
from orion_eval.world import ACTION_WORDS, Body

_LETTER = {1: "f", 2: "l", 3: "r"}


class EpisodeOver(Exception):
    """Raised inside the agent's code when the episode ends; ``reason`` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class Task:
    scene: str
    method: str
    feedback: str
    seed: int
    goal_id: str
    episode_id: str
    start: tuple[float, float, float]
    geodesic_m: float
    start_floor: int | None = None  # the floor the start is on (a building); None: routes.zarr's for ``episode_id``


@dataclass
class EpisodeRun:
    """The running episode: the body, the user, counters and the dialogue."""

    ctx: object
    task: Task
    user: SimulatedUser
    max_steps: int
    max_talk: int
    body: Body = None
    talk_turns: int = 0
    success: bool = False
    dialogue: list = field(default_factory=list)
    events: list = field(default_factory=list)

    memory: object = None  # an ORION memory carried across the scene's goals, or None (fresh)

    def __post_init__(self):
        x, y, yaw = self.task.start
        self.start_floor = self.task.start_floor
        if self.start_floor is None:
            self.start_floor = self.ctx.episode_floor(self.task.episode_id)
        self.body = Body(float(x), float(y), float(yaw), floor=self.start_floor)
        self.body.poses.append((round(x, 4), round(y, 4), round(yaw, 4)))
        self.body.floors.append(self.start_floor)
        self.modules = Modules(self, memory=self.memory)

    def act(self, action: int) -> bool:
        """Execute one action; False when a forward step collided (the agent stays put)."""
        if self.body.steps >= self.max_steps:
            raise EpisodeOver("step budget")
        return self.ctx.world.act(self.body, action)

    def log_event(self, kind: str, detail: str) -> None:
        self.events.append((self.body.steps, kind, detail))

    def talk(self, content: str) -> str:
        self.talk_turns += 1
        self.dialogue.append({"speaker": "agent", "text": content, "step": self.body.steps,
                              "pose": [round(v, 3) for v in self.body.pose]})
        ok, reply, kind = self.user.respond(self.body.pose, content)
        if reply:
            self.dialogue.append({"speaker": "user", "text": reply, "kind": kind, "step": self.body.steps})
        if ok:
            self.success = True
            raise EpisodeOver("success")
        if self.task.feedback == "none":
            raise EpisodeOver("no interaction")
        if self.talk_turns >= self.max_talk:
            raise EpisodeOver("talk budget")
        return reply

    def result(self, reason: str) -> dict:
        """Metrics and the log of the finished episode (plain JSON-able data)."""
        t, b = self.task, self.body
        s = 1.0 if self.success else 0.0
        l, a = float(t.geodesic_m), float(b.travelled_m)
        final = self.user.judge(b.pose)
        out = {
            "scene": t.scene, "method": t.method, "feedback": t.feedback, "seed": t.seed, "goal": t.goal_id,
            "goal_type": self.user.goal.type, "episode": t.episode_id, "success": bool(self.success),
            "spl": spl(s, l, a), "sit": sit(s, self.talk_turns), "talk_turns": self.talk_turns,
            "steps": b.steps, "travelled_m": round(a, 4), "geodesic_m": round(l, 4), "collisions": b.collisions,
            "end": reason, "final_distance_m": final["distance_m"],
            "log": {"start": list(t.start), "instruction": self.user.instruction(),
                    "actions": "".join(_LETTER.get(x, "?") for x in b.actions),
                    "action_words": {v: ACTION_WORDS[k] for k, v in _LETTER.items()},
                    "poses": [list(p) for p in b.poses], "dialogue": self.dialogue,
                    "events": [list(e) for e in self.events]},
        }
        if self.ctx.is_building:
            goal_floor = self.user.goal.floor
            out.update(start_floor=self.start_floor, goal_floor=goal_floor, cross_floor=self.start_floor != goal_floor,
                       final_floor=b.floor)
            out["log"]["floors"] = list(b.floors)
        return out


def spl(success: float, l: float, a: float) -> float:
    """S * l / max(a, l) (0 when l and a are both 0 and S = 0)."""
    if success <= 0:
        return 0.0
    d = max(a, l)
    return float(success * l / d) if d > 0 else float(success)


def sit(success: float, talk_turns: int) -> float:
    """S / I with I >= 1."""
    return float(success / max(1, int(talk_turns)))


def run_episode(ctx, task: Task, agent, goal, *, rng: np.random.Generator, llm_user=None, memory=None) -> dict:
    """Run one episode to its end; returns :meth:`EpisodeRun.result`. ``llm_user(goal)`` makes an LLM user;
    ``memory`` (a :class:`~orion_eval.memory.MemoryMaps`) is the agent's memory carried from earlier goals."""
    ep = ctx.params.eval
    user = SimulatedUser(ctx, goal, task.feedback, rng)
    if llm_user is not None:
        user.llm = llm_user(goal)
    run = EpisodeRun(ctx, task, user, ep.max_steps, ep.max_talk_turns, memory=memory)
    try:
        run_agent(agent, run.modules, user.instruction(), goal.name, passes=(EpisodeOver,))
        reason = "gave up"
    except EpisodeOver as over:
        reason = over.reason
    return run.result(reason)


def start_pose(start, seed: int, n_episodes: int) -> tuple[float, float, float]:
    """The start heading is turned by 90 deg per pass over a goal's episodes (seeds beyond their count)."""
    x, y, yaw = start
    turns = seed // max(1, n_episodes)
    return (float(x), float(y), float(math.remainder(yaw + turns * math.pi / 2, 2 * math.pi)))
