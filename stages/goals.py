"""Stage ``goals``: objects (GT in frames.zarr, a user file, or navchat annotations) -> ``goals.zarr``.

The work (objects, walls, goal regions, procedural feedback planned as the routes stage plans, user edits) is
:func:`pipeline.goals.build.build_scene_goals`; this module holds the stage's config and entry point.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.config import GoalsParams, Params, TaskParams
from pipeline.stageconfig import StageConfig, section_keys

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext


# goals.* entries keyed by scene: a scene's config holds only its own entry
PER_SCENE = ("objects_files", "navchat_dirs", "edits")
# task.* facts the goals stage reads: the success radius cuts the goal regions, the rest plans procedural
# feedback as the routes stage plans its episodes (task.hfov_deg is not read: it stays at its default here)
TASK_KEYS = ("step_m", "turn_deg", "clearance_m", "stop_radius_m", "success_m")


class Config(StageConfig):
    """The ``goals`` section (of the scene-keyed entries, only this scene's) and the ``task`` facts of
    :data:`TASK_KEYS`, so importing goal edits for one scene leaves every other scene up to date."""

    goals: GoalsParams
    task: TaskParams

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        own = [f"goals.{k}.{scene}" for k in PER_SCENE if scene in getattr(params.goals, k)]
        return section_keys("goals", GoalsParams, exclude=PER_SCENE) + own + [f"task.{k}" for k in TASK_KEYS]

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "Config":
        g = params.goals
        goals = g.model_copy(update={k: {s: v for s, v in getattr(g, k).items() if s == scene} for k in PER_SCENE})
        return cls(goals=goals, task=TaskParams(**{k: getattr(params.task, k) for k in TASK_KEYS}))

    @classmethod
    def extra_inputs(cls, params: Params, scene: str) -> dict[str, str]:
        g = params.goals
        named = {"objects_file": g.objects_files, "navchat_dir": g.navchat_dirs, "goal_edits": g.edits}
        return {name: paths[scene] for name, paths in named.items() if scene in paths}


def run(ctx: StageContext) -> dict:
    """Write ``ctx.outputs['goals']`` from the scene's frames and recon; returns the summary."""
    # here: the goal builder's imports (scipy.ndimage, scikit-fmm, opencv) cost every `zipon status`
    from pipeline.frames import FrameStore
    from pipeline.goals.build import build_scene_goals
    from pipeline.goals.store import ARTIFACT, FORMAT_VERSION
    from pipeline.recon import Recon
    from pipeline.store import artifact_attrs

    return build_scene_goals(FrameStore(ctx.inputs["frames"]), Recon(ctx.inputs["recon"]), ctx.outputs["goals"],
                             artifact_attrs(ARTIFACT, FORMAT_VERSION, "goals", ctx.params_digest), scene=ctx.scene,
                             goals=ctx.config.goals, task=ctx.config.task, root=ctx.workspace.root, log=ctx.log)
