"""Stage ``routes``: goals + recon's navigable grid -> episodes with verified geodesic routes (``routes.zarr``).

The work (seeded starts, FMM routes into the goals' stored regions, actions, text, replay verification) is
:func:`pipeline.routes.build.build_routes`; this module holds the stage's config and entry point.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.config import RoutesParams, TaskParams
from pipeline.stageconfig import StageConfig

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext


class Config(StageConfig):
    """The ``routes`` section and the ``task`` (action space, success radius and view, stop radius, clearance)."""

    routes: RoutesParams
    task: TaskParams


def run(ctx: StageContext) -> dict:
    """Write ``ctx.outputs['routes']`` from the scene's goals and recon; returns the summary."""
    # here: the route planner's imports (scikit-fmm, scipy.ndimage) cost every `zipon status`
    from pipeline.goals.store import Goals
    from pipeline.recon import Recon
    from pipeline.routes.build import build_routes
    from pipeline.routes.store import ARTIFACT, FORMAT_VERSION
    from pipeline.store import artifact_attrs

    attrs = artifact_attrs(ARTIFACT, FORMAT_VERSION, "routes", ctx.params_digest, scene=ctx.scene)
    return build_routes(Goals(ctx.inputs["goals"]), Recon(ctx.inputs["recon"]), ctx.outputs["routes"], attrs,
                        ctx.config.routes, ctx.config.task, log=ctx.log,
                        progress=lambda it, n, d: ctx.progress(it, total=n, description=d))
