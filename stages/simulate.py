"""Stage ``simulate``: a procedural indoor scene rendered along an exploration trajectory -> ROS 2 MCAP log."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.config import SimulateParams
from pipeline.stageconfig import StageConfig

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext


class Config(StageConfig):
    """The ``simulate`` section (each scene's seed is derived from ``simulate.seed`` and the scene name)."""

    simulate: SimulateParams


def run(ctx: StageContext) -> dict:
    """Write ``ctx.outputs['raw_log']`` for scene ``ctx.scene`` with ``ctx.config.simulate``; returns the summary."""
    from pipeline.sim import simulate_scene  # here: the renderer's imports cost every `zipon status` ~1 s

    summary = simulate_scene(ctx.scene, ctx.config.simulate, ctx.outputs["raw_log"],
                             progress=lambda it, total: ctx.progress(it, total=total, description="render"))
    ctx.log(f"{summary['frames']} frames, {summary['rooms']} rooms, {summary['objects']} objects "
            f"({summary['classes']} classes) in {summary['seconds']:.1f} s")
    return summary
