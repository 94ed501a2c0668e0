"""The agents (scripted, and the LLM's): one interface (:class:`~orion_eval.agents.base.Agent`), one file each,
declared by name in :data:`pipeline.plugins.BUILT_IN_AGENTS` (installed packages add theirs in the ``zipon.agents``
entry points); :func:`~orion_eval.agents.base.agent_class` resolves a name."""

from pipeline import plugins
from orion_eval.agents.base import (AGENTS, Agent, AgentResources, ParsedFeedback, agent_class, all_agents,
                                    build_agent, parse_feedback, run_agent)

for _name in plugins.BUILT_IN_AGENTS:  # the built-in agents, loaded in their declared order (the paper's table)
    agent_class(_name)

__all__ = ["AGENTS", "Agent", "AgentResources", "ParsedFeedback", "agent_class", "all_agents", "build_agent",
           "parse_feedback", "run_agent"]
