"""Procedural indoor scenes (embedded default data): ground truth, ray-cast RGB-D frames, MCAP logs.

- :func:`generate_scene` -> :class:`~pipeline.scene_gt.GTScene` (deterministic per seed and name)
- :class:`SceneRaycaster` renders RGB / z-depth / instance ids of any ``T_world_camera`` batch
- :func:`simulate_scene` writes a whole ROS 2 MCAP log; :func:`render_scene_png` draws the floor plan

The names are imported on first use (PEP 562 ``__getattr__``): the simulated encoders' text side needs only
:mod:`pipeline.sim.catalog`, and importing the renderer and furnisher (scipy.ndimage, ~0.5 s) would cost
every ``zipon query`` on a simulated scene.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pipeline.sim.raycast import RaycastFrames, SceneRaycaster
    from pipeline.sim.scene import generate_scene, scene_seed
    from pipeline.sim.simulate import SimulatedRecording, simulate_scene
    from pipeline.sim.topdown import FloorTruth, draw_scene_topdown, floor_truths, render_scene_png
    from pipeline.sim.trajectory import free_space, plan_actions

__all__ = ["FloorTruth", "RaycastFrames", "SceneRaycaster", "SimulatedRecording", "draw_scene_topdown",
           "floor_truths", "free_space", "generate_scene", "plan_actions", "render_scene_png", "scene_seed",
           "simulate_scene"]


def __getattr__(name: str):
    # explicit imports, not importlib with a computed name: pipeline.engine.codedeps reads them (a stage's code closure)
    if name in ("RaycastFrames", "SceneRaycaster"):
        from pipeline.sim import raycast as module
    elif name in ("generate_scene", "scene_seed"):
        from pipeline.sim import scene as module
    elif name in ("SimulatedRecording", "simulate_scene"):
        from pipeline.sim import simulate as module
    elif name in ("FloorTruth", "draw_scene_topdown", "floor_truths", "render_scene_png"):
        from pipeline.sim import topdown as module
    elif name in ("free_space", "plan_actions"):
        from pipeline.sim import trajectory as module
    else:
        raise AttributeError(f"module 'pipeline.sim' has no attribute {name!r}")
    return getattr(module, name)
