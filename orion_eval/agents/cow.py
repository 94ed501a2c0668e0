"""``cow``: CLIP-on-Wheels — frontier exploration and CLIP Grad-CAM saliency localisation; no map, no memory."""

from __future__ import annotations

from orion_eval.agents.controller import ModularAgent, ModuleSet


class CowAgent(ModularAgent):
    """The controller with exploration and CoW's own (simulated) CLIP-saliency detector."""

    name, label, colour = "cow", "CoW", "#ff7f0e"
    modules = ModuleSet(detector="saliency", explore=True)
