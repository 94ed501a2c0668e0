"""``orion``: every module — the semantic map (``eval.orion_map``), exploration, the grounded detector and
memory, run by the one controller (:mod:`orion_eval.agents.controller`).

ORION's ablations (the paper's Table II, lower part: ORION with one module taken away, in the mixed setting) are the
same controller with that module left out of the set. They run only when named (``-m orion_wo_map``):

- ``orion_wo_mem``: no memory;
- ``orion_wo_exp``: no exploration; with nothing left to try it still looks around where it stands (the paper's
  "w/o exp" keeps the 360° spin);
- ``orion_wo_det``: CoW's CLIP-saliency localiser in place of the grounded detector (the paper replaces Grounded-SAM
  with CoW's k-patch CLIP matching: coarse patches scored by CLIP, as the saliency detector's are);
- ``orion_wo_map``: no semantic map.
"""

from __future__ import annotations

from orion_eval.agents.controller import ModularAgent, ModuleSet


class OrionAgent(ModularAgent):
    name, label, colour = "orion", "ORION", "#d62728"
    modules = ModuleSet(map="orion", detector="grounded", explore=True, memory=True)
    persistent_memory = True  # the memory is carried across the goals of a scene (evaluate_scene)


class OrionWithoutMemory(OrionAgent):
    name, label, colour = "orion_wo_mem", "ORION w/o mem", "#e377c2"
    modules = ModuleSet(map="orion", detector="grounded", explore=True)
    persistent_memory = False
    by_default = False


class OrionWithoutExploration(OrionAgent):
    name, label, colour = "orion_wo_exp", "ORION w/o exp", "#8c564b"
    modules = ModuleSet(map="orion", detector="grounded", memory=True)
    by_default = False


class OrionWithoutDetection(OrionAgent):
    name, label, colour = "orion_wo_det", "ORION w/o det", "#7f7f7f"
    modules = ModuleSet(map="orion", detector="saliency", explore=True, memory=True)
    by_default = False


class OrionWithoutMap(OrionAgent):
    name, label, colour = "orion_wo_map", "ORION w/o map", "#bcbd22"
    modules = ModuleSet(detector="grounded", explore=True, memory=True)
    by_default = False
