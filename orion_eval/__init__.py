"""The light online evaluator: ORION-style agents on zipon's artifacts, a simulated user, metrics, reports.

Modules (the scene handle with its lineage check is the library's :class:`pipeline.scene.Scene`):
:mod:`~orion_eval.world` (actions, collisions, success rule), :mod:`~orion_eval.nav` (FMM planner), :mod:`~orion_eval.egoview`
(ego views ray-cast from the reconstructed mesh), :mod:`~orion_eval.scene` (per-scene caches, detection),
:mod:`~orion_eval.modules` (the ORION API), :mod:`~orion_eval.memory`, :mod:`~orion_eval.user`
(simulated user), :mod:`~orion_eval.agents` (policies), :mod:`~orion_eval.episode`,
:mod:`~orion_eval.metrics`, :mod:`~orion_eval.report`, :mod:`~orion_eval.llm` (optional LLM user/agent),
:mod:`~orion_eval.run` (``evaluate``, behind :func:`zipon.run_eval`).
"""

from orion_eval.run import evaluate

__all__ = ["evaluate"]
