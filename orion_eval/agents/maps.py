"""``vlmap`` / ``cf``: map retrieval only (VLMaps' LSeg map, ConceptFusion's map) — no detection, exploration or
memory. Both run the one controller (:mod:`orion_eval.agents.controller`) and differ only in their map."""

from __future__ import annotations

from orion_eval.agents.controller import ModularAgent, ModuleSet


class VLMapAgent(ModularAgent):
    name, label, colour = "vlmap", "VLMap", "#2ca02c"
    modules = ModuleSet(map="vlmap")


class CFAgent(ModularAgent):
    name, label, colour = "cf", "CF", "#9467bd"
    modules = ModuleSet(map="cfmap")
