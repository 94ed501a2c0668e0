"""Procedural indoor scenes (embedded default data): ground truth, ray-cast RGB-D frames, MCAP logs.

- :func:`generate_scene` -> :class:`~pipeline.scene_gt.GTScene` (deterministic per seed and name)
- :class:`SceneRenderer` renders RGB / z-depth / instance ids of any ``T_world_camera`` batch
- :func:`simulate_scene` writes a whole ROS 2 MCAP log; :func:`render_scene_png` draws the floor plan
"""

from pipeline.sim.render import RenderedFrames, SceneRenderer
from pipeline.sim.scene import generate_scene, scene_seed
from pipeline.sim.simulate import SimulatedRecording, simulate_scene
from pipeline.sim.topdown import draw_scene_topdown, render_scene_png
from pipeline.sim.trajectory import free_space, plan_actions

__all__ = ["RenderedFrames", "SceneRenderer", "SimulatedRecording", "draw_scene_topdown", "free_space",
           "generate_scene", "plan_actions", "render_scene_png", "scene_seed", "simulate_scene"]
