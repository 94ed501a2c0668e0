"""The light online evaluator: ORION-style agents on zipon's artifacts, a simulated user, metrics, reports.

Modules: :mod:`~orion_eval.artifacts` (lazy scene view + lineage check), :mod:`~orion_eval.world`
(actions, collisions, success rule), :mod:`~orion_eval.nav` (FMM planner), :mod:`~orion_eval.egoview`
(ego views ray-cast from the reconstructed mesh), :mod:`~orion_eval.scene` (per-scene caches, detection),
:mod:`~orion_eval.modules` (the ORION API), :mod:`~orion_eval.memory`, :mod:`~orion_eval.user`
(simulated user), :mod:`~orion_eval.agents` (policies), :mod:`~orion_eval.episode`,
:mod:`~orion_eval.metrics`, :mod:`~orion_eval.report`, :mod:`~orion_eval.llm` (optional LLM user/agent),
:mod:`~orion_eval.run` (``run_eval``, the ``zipon eval`` entry point).
"""

from orion_eval.artifacts import Artifacts
from orion_eval.run import run_eval

__all__ = ["Artifacts", "run_eval"]
