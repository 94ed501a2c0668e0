"""The agents (scripted, and the LLM's): one interface (:class:`~orion_eval.agents.base.Agent`), a registry, one file each."""

from orion_eval.agents.base import AGENTS, Agent, AgentResources, ParsedFeedback, build_agent, parse_feedback
from orion_eval.agents import human, cow, maps, orion, llm  # noqa: F401  (registration: the paper's table order, then the LLM)

__all__ = ["AGENTS", "Agent", "AgentResources", "ParsedFeedback", "build_agent", "parse_feedback"]
