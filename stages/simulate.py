"""Stage ``simulate``: a procedural indoor scene rendered along an exploration trajectory -> ROS 2 MCAP log."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.config import BuildingParams, Params, SimulateParams
from pipeline.stageconfig import StageConfig

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext


class Config(StageConfig):
    """The ``simulate`` section (each scene's seed is derived from ``simulate.seed`` and the scene name) and the
    scene's ``scenes.<name>.building`` (a house or an office; absent: an apartment, whose digest stays as it was)."""

    simulate: SimulateParams
    building: BuildingParams | None = None

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        return ["simulate"] + ([f"scenes.{scene}.building"] if params.scenes[scene].building is not None else [])

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "Config":
        return cls(simulate=params.simulate, building=params.scenes[scene].building)


def run(ctx: StageContext) -> dict:
    """Write ``ctx.outputs['raw_log']`` for scene ``ctx.scene`` with ``ctx.config.simulate``; returns the summary."""
    from pipeline.sim import simulate_scene  # here: the renderer's imports cost every `zipon status` ~1 s

    summary = simulate_scene(ctx.scene, ctx.config.simulate, ctx.outputs["raw_log"], building=ctx.config.building,
                             progress=lambda it, total: ctx.progress(it, total=total, description="render"))
    floors = f", {summary['floors']} floors" if "floors" in summary else ""
    ctx.log(f"{summary['frames']} frames, {summary['rooms']} rooms{floors}, {summary['objects']} objects "
            f"({summary['classes']} classes) in {summary['seconds']:.1f} s")
    return summary
