"""``orion``: every module — the semantic map (``eval.orion_map``), exploration, the grounded detector and
memory, run by the one controller (:mod:`orion_eval.agents.controller`)."""

from __future__ import annotations

from orion_eval.agents.base import register
from orion_eval.agents.controller import ModularAgent, ModuleSet


@register
class OrionAgent(ModularAgent):
    name, label, colour = "orion", "ORION", "#d62728"
    modules = ModuleSet(map="orion", detector="grounded", explore=True, memory=True)
    persistent_memory = True  # the memory is carried across the goals of a scene (evaluate_scene)
