"""The agent interface, its registry, and the parser of the user's replies every agent shares.

An agent gets the episode's :class:`~orion_eval.modules.Modules` (the ORION API), the user's
instruction and the goal's name, and acts until the episode ends (the modules raise
:class:`~orion_eval.episode.EpisodeOver`) or it gives up (returns).

:func:`parse_feedback` reads the simulated user's templates (the same a person would type):
"Yes ...", "No.", "No. This is X, not Y." (corrective), "No. It is a red chair made of wood. ..."
(descriptive), "No. It is next to X and near Y." (landmark), "No. Follow this route: turn left,
go forward 5 meters." or "No. It is about 4 meters ahead on your left." (procedural: a route, or a
destination point); in the mixed setting one reply may hold several of them.
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

RELATIONS = ("next to", "near", "on", "under")
#: how the user points at a destination, and its bearing (degrees, counter-clockwise from ahead)
DIRECTIONS = {"ahead on your left": 45.0, "ahead on your right": -45.0, "ahead": 0.0, "to your left": 90.0,
              "to your right": -90.0, "behind you on the left": 135.0, "behind you on the right": -135.0,
              "behind you": 180.0}


@dataclass
class ParsedFeedback:
    yes: bool = False
    corrected_as: str | None = None  # corrective: what the agent found instead
    description: str | None = None  # descriptive: "red chair made of wood"
    landmarks: list[str] = field(default_factory=list)  # landmark phrases: ["Alice's bed"]
    route: list[tuple[str, float]] = field(default_factory=list)  # procedural: [("turn", deg), ("forward", m)]
    destination: tuple[float, float] | None = None  # procedural point: (bearing deg, left positive; distance m)


def parse_route(text: str) -> list[tuple[str, float]]:
    out = []
    for part in (p.strip().lower() for p in text.split(",")):
        if part.startswith("turn around"):
            out.append(("turn", 180.0))
        elif part.startswith("turn left"):
            out.append(("turn", 90.0))
        elif part.startswith("turn right"):
            out.append(("turn", -90.0))
        else:
            m = re.match(r"go forward ([\d.]+) meters?", part)
            if m:
                out.append(("forward", float(m.group(1))))
    return out


def parse_feedback(reply: str) -> ParsedFeedback:
    """Structured content of a user reply (see the module docstring)."""
    fb = ParsedFeedback()
    text = (reply or "").strip()
    if text.lower().startswith("yes"):
        fb.yes = True
        return fb
    m = re.search(r"This is (.+?), not (.+?)\.(\s|$)", text)
    if m:
        fb.corrected_as = m.group(1)
    m = re.search(r"Follow this route: (.+?)\.?$", text)
    if m:
        fb.route = parse_route(m.group(1))
    ways = "|".join(re.escape(d) for d in DIRECTIONS)  # longest first: "ahead on your left" before "ahead"
    m = re.search(rf"It is about ([\d.]+) meters? ({ways})\.", text)
    if m:
        fb.destination = (DIRECTIONS[m.group(2)], float(m.group(1)))
    m = re.search(r"It is (?:a|an) (.+?)\.", text)
    if m:
        fb.description = m.group(1)
    m = re.search(r"It is ((?:next to|near|on|under) .+?)\.(\s|$)", text)
    if m:
        rel = "|".join(re.escape(r) for r in RELATIONS)
        for piece in re.split(r",\s*|\s+and\s+", m.group(1)):
            piece = re.sub(rf"^({rel})\s+", "", piece.strip())
            if piece:
                fb.landmarks.append(piece)
    return fb


@dataclass(frozen=True)
class AgentResources:
    """What the evaluator lends the agents of one scene beside the params: ``llm``, the chat client of ``eval.llm``
    (one per scene, shared with the LLM user so that ``eval.llm.max_requests`` bounds both; None when no endpoint
    is set)."""

    llm: Any = None


class Agent(ABC):
    """A scripted policy over the ORION modules."""

    name: str = ""
    label: str = ""  # how tables and figures name the method (defaults to ``name``)
    colour: str = ""  # its fixed colour in every figure ("#rrggbb"; empty: one derived from the name)
    upper_bound: bool = False  # follows the ground truth: shown for reference, never "best" or starred
    persistent_memory: bool = False  # True: evaluate_scene carries the agent's memory across a scene's goals
    by_default: bool = True  # evaluated when no method is named (False: only when named)

    def __init__(self, params):
        self.params = params  # the whole Params

    @classmethod
    def missing(cls, params) -> str | None:
        """What ``params`` lack for this agent to run, in words (None: nothing)."""
        return None

    @classmethod
    def build(cls, params, resources: AgentResources) -> "Agent":
        """The agent of one scene: every agent, built in, installed or the caller's, is made here."""
        return cls(params)

    @abstractmethod
    def run(self, m, instruction: str, goal_name: str) -> None:
        """Act until the episode ends or give up (return)."""

    # shared helpers -----------------------------------------------------------
    @staticmethod
    def follow_route(m, route: list[tuple[str, float]]) -> None:
        for kind, value in route:
            if kind == "turn":
                m.rotate(math.radians(value))
            else:
                m.move(value)

    @staticmethod
    def near_any(m, obj_id: int, places: list, radius: float) -> bool:
        c = m.objects[obj_id].center_xy
        return any(math.hypot(c[0] - p[0], c[1] - p[1]) <= radius for p in places)


AGENTS: dict[str, type[Agent]] = {}


def register(cls: type[Agent]) -> type[Agent]:
    AGENTS[cls.name] = cls
    return cls


def build_agent(name: str, params, resources: AgentResources = AgentResources(),
                classes: dict[str, type[Agent]] | None = None) -> Agent:
    """The agent ``name`` of the registry (or of ``classes``, the caller's own agents) for one scene."""
    cls = (classes or {}).get(name) or AGENTS.get(name)
    if cls is None:
        from pipeline.errors import ConfigError

        raise ConfigError(f"eval.methods: unknown agent {name!r} (choose from {sorted(AGENTS)})")
    return cls.build(params, resources)
