"""Stage ``simulate``: a procedural indoor scene rendered along an exploration trajectory -> ROS 2 MCAP log."""

from __future__ import annotations

from pipeline.runner import StageContext
from pipeline.sim import simulate_scene


def run(ctx: StageContext) -> dict:
    """Write ``ctx.outputs['raw_log']`` for scene ``ctx.scene`` with ``ctx.params.simulate``; returns the summary."""
    params = ctx.params.simulate
    summary = simulate_scene(ctx.scene, params, ctx.outputs["raw_log"],
                             progress=lambda it, total: ctx.progress(it, total=total, description="render"))
    ctx.log(f"{summary['frames']} frames, {summary['rooms']} rooms, {summary['objects']} objects "
            f"({summary['classes']} classes) in {summary['seconds']:.1f} s")
    return summary
