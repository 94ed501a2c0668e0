"""The navigation toolkit every part shares: the routes stage, the evaluator and the annotation workbench.

Modules: :mod:`~pipeline.nav.fmm` (fast-marching fields and shortest paths on a navigable grid),
:mod:`~pipeline.nav.actions` (15 deg / 0.25 m actions, navchat's text rules, :func:`~pipeline.nav.actions.procedural_instruction`
from any pose), :mod:`~pipeline.nav.region` (goal regions, route aims and :func:`~pipeline.nav.region.route_to_goal`,
the one planner of a route into a goal's region), :mod:`~pipeline.nav.verify` (replaying a route on the grid).
"""
