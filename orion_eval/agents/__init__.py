"""Scripted agents: one interface (:class:`~orion_eval.agents.base.Agent`), a registry, one file each."""

from orion_eval.agents.base import AGENTS, Agent, ParsedFeedback, build_agent, parse_feedback
from orion_eval.agents import human, cow, maps, orion  # noqa: F401  (registration, in the paper's table order)

__all__ = ["AGENTS", "Agent", "ParsedFeedback", "build_agent", "parse_feedback"]
