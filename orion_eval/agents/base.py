"""The agent interface, its registry, and the parser of the user's replies every agent shares.

An agent gets the episode's :class:`~orion_eval.modules.Modules` (the ORION API), the user's
instruction and the goal's name, and acts until the episode ends (the modules raise
:class:`~orion_eval.episode.EpisodeOver`) or it gives up (returns).

:func:`parse_feedback` reads the simulated user's templates (the same a person would type): "Yes ...", "No.", or
"No." and what one or more feedback kinds say, each read by its kind's
:meth:`~pipeline.goals.feedback.base.FeedbackKind.parse` (the kind's module holds its phrases and their reading):
"No. This is X, not Y." (corrective), "No. It is a red chair made of wood. ..." (descriptive), "No. It is next to X
and near Y." (landmark), "No. Follow this route: turn left, go forward 5 meters." or "No. It is about 4 meters ahead
on your left." (procedural: a route, or a destination point); in the mixed setting one reply may hold several.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

from pipeline import plugins
from pipeline.errors import ConfigError
from pipeline.goals.feedback import FEEDBACK_KINDS


class ParsedFeedback:
    """What a reply says: ``yes``, and the attributes each feedback kind's
    :meth:`~pipeline.goals.feedback.base.FeedbackKind.parse` fills (declared in its ``parsed``): ``corrected_as``
    (corrective: what the agent found instead), ``description`` (descriptive: "red chair made of wood"),
    ``landmarks`` (landmark phrases: ["Alice's bed"]), ``route`` (procedural: [("turn", deg), ("forward", m)]) and
    ``destination`` (procedural point: (bearing deg, left positive; distance m)). An attribute the reply says nothing
    of holds its kind's empty value (None, [])."""

    def __init__(self, yes: bool = False, **said: Any):
        self.yes = yes
        for kind in FEEDBACK_KINDS.values():
            for attr, empty in kind.parsed.items():
                setattr(self, attr, said.pop(attr) if attr in said else empty())
        if said:
            raise TypeError(f"ParsedFeedback: {sorted(said)} are filled by no feedback kind "
                            f"(pipeline.goals.feedback: {sorted(FEEDBACK_KINDS)})")

    def __eq__(self, other) -> bool:
        return isinstance(other, ParsedFeedback) and vars(self) == vars(other)

    def __repr__(self) -> str:
        return f"ParsedFeedback({', '.join(f'{k}={v!r}' for k, v in vars(self).items())})"


def parse_feedback(reply: str) -> ParsedFeedback:
    """Structured content of a user reply (see the module docstring): "Yes ..." or what each kind reads in it."""
    text = (reply or "").strip()
    if text.lower().startswith("yes"):
        return ParsedFeedback(yes=True)
    return ParsedFeedback(**{attr: value for kind in FEEDBACK_KINDS.values()
                             for attr, value in kind().parse(text).items()})


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


#: the agents loaded so far, by name (filled by :func:`agent_class`; importing :mod:`orion_eval.agents` loads the
#: built-in ones, in their declared order)
AGENTS: dict[str, type[Agent]] = {}


def agent_class(name: str) -> type[Agent] | None:
    """The agent ``name``, built in (:data:`pipeline.plugins.BUILT_IN_AGENTS`) or registered by an installed package
    (``zipon.agents`` entry points); None for a name neither declares. Raises ConfigError naming the entry point and
    its package when a registration does not load or does not fit."""
    return plugins.load_class(plugins.AGENTS_GROUP, name, Agent, "orion_eval.agents.Agent", "agent", loaded=AGENTS)


def all_agents() -> dict[str, type[Agent]]:
    """Every agent of the registry by name: the built-in ones, then the installed packages' (sorted)."""
    return {name: agent_class(name) for name in plugins.agent_names()}


def build_agent(name: str, params, resources: AgentResources = AgentResources(),
                classes: dict[str, type[Agent]] | None = None) -> Agent:
    """The agent ``name`` of the registry (or of ``classes``, the caller's own agents) for one scene; an installed
    one failing to build is a PluginError naming its entry point."""
    cls = (classes or {}).get(name) or agent_class(name)
    if cls is None:
        raise ConfigError(f"eval.methods: unknown agent {name!r} (choose from {plugins.agent_names()})")
    with plugins.running(cls, "build"):
        return cls.build(params, resources)


def run_agent(agent: Agent, m, instruction: str, goal_name: str, passes: tuple[type[BaseException], ...]) -> None:
    """``agent.run(...)``; an installed agent's failure (not ``passes``: the episode's end) is a PluginError naming
    its entry point and package."""
    with plugins.running(type(agent), "run", passes):
        agent.run(m, instruction, goal_name)
