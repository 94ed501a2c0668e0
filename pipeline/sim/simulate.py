"""One simulated scene end to end: generate, plan, render in blocks, write the ROS 2 MCAP log."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pipeline.config import BuildingParams, SimulateParams
from pipeline.geometry import Intrinsics, interpolate_poses
from pipeline.scene_gt import GTScene
from pipeline.sim.raycast import SceneRaycaster
from pipeline.sim.scene import STREAM_DEPTH_NOISE, STREAM_POSE_NOISE, generate_scene, scene_rng
from pipeline.sim.trajectory import plan_actions, sample_trajectory

START_NS = 1_704_067_200 * 10**9  # 2024-01-01T00:00:00Z: every simulated log starts here


def add_depth_noise(depth_m: np.ndarray, sigma_at_1m: float, seed: int, first_frame: int) -> np.ndarray:
    """Depth ``(B,H,W)`` plus N(0, sigma * z^2) noise; each frame's noise depends only on its index."""
    if sigma_at_1m <= 0:
        return depth_m
    out = depth_m.copy()
    for i in range(len(depth_m)):
        noise = scene_rng(seed, STREAM_DEPTH_NOISE, first_frame + i).standard_normal(depth_m.shape[1:], np.float32)
        out[i] = depth_m[i] + np.float32(sigma_at_1m) * depth_m[i] * depth_m[i] * noise
    return out


def jitter_poses(T: np.ndarray, params: SimulateParams, seed: int) -> np.ndarray:
    """Recorded poses ``(N,4,4)``: x/y moved by N(0, pose_jitter_m), heading turned by N(0, pose_jitter_deg)
    about world z (a wheeled robot's odometry noise; height, roll and pitch stay exact)."""
    if params.pose_jitter_m <= 0 and params.pose_jitter_deg <= 0:
        return T
    rng = scene_rng(seed, STREAM_POSE_NOISE)
    dxy = rng.standard_normal((len(T), 2)) * params.pose_jitter_m
    dyaw = np.deg2rad(rng.standard_normal(len(T)) * params.pose_jitter_deg)
    c, s = np.cos(dyaw), np.sin(dyaw)
    Rz = np.zeros((len(T), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    out = T.copy()
    out[:, :3, :3] = Rz @ T[:, :3, :3]
    out[:, :2, 3] += dxy
    return out


class SimulatedRecording:
    """A planned recording of one scene: ground truth, true frame poses and the recorded pose stream."""

    def __init__(self, scene: str, params: SimulateParams, gt: GTScene | None = None,
                 building: BuildingParams | None = None):
        self.params = params
        self.gt = gt if gt is not None else generate_scene(scene, params, building)
        self.intrinsics = Intrinsics.from_hfov(params.width, params.height, params.hfov_deg)
        min_actions = int(np.ceil(params.min_actions_per_frame * params.frames))
        states, self.visited = plan_actions(self.gt, params.robot_radius_m, min_actions)
        self.actions = len(states) - 1
        self.states = states
        key_ns, key_T, self.frame_ns, self.frame_T = sample_trajectory(
            states, params.frames, params.fps, params.camera_height_m, START_NS)
        n_pose = int(np.floor((key_ns[-1] - key_ns[0]) * 1e-9 * params.pose_rate_hz)) + 1
        pose_ns = key_ns[0] + np.round(np.arange(n_pose) * 1e9 / params.pose_rate_hz).astype(np.int64)
        if pose_ns[-1] < key_ns[-1]:
            pose_ns = np.append(pose_ns, key_ns[-1])  # the last frame is bracketed by poses
        self.pose_ns = pose_ns
        self.true_pose_T = interpolate_poses(key_ns, key_T, pose_ns)
        self.recorded_pose_T = jitter_poses(self.true_pose_T, params, self.gt.seed)

    def blocks(self, raycaster: SceneRaycaster) -> Iterable[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
        """``(first, rgb (B,H,W,3) uint8, depth_mm (B,H,W) uint16, instance (B,H,W) uint16)`` per block."""
        p = self.params
        for start in range(0, p.frames, p.render_block_frames):
            stop = min(start + p.render_block_frames, p.frames)
            out = raycaster.raycast(self.frame_T[start:stop])
            out.depth_m = add_depth_noise(out.depth_m, p.depth_noise_m, self.gt.seed, start)
            yield start, out.rgb, out.depth_mm(p.depth_min_m, p.depth_max_m), out.instance


def frame_floors(gt: GTScene, frame_T: np.ndarray, camera_height_m: float) -> np.ndarray:
    """``(N,)`` int: the floor each frame's camera stands on (the floor whose band holds the walking surface
    under it; on a flight, the floor below its middle)."""
    return np.array([gt.floor_at(float(z) - camera_height_m + 0.5 * _min_story(gt)) for z in frame_T[:, 2, 3]])


def _min_story(gt: GTScene) -> float:
    floors = gt.all_floors
    return min((b.floor_z - a.floor_z for a, b in zip(floors[:-1], floors[1:])), default=0.0)


def simulate_scene(scene: str, params: SimulateParams, out_path: Path, *, building: BuildingParams | None = None,
                   progress: Callable[[Iterable, int], Iterable] | None = None) -> dict:
    """Generate scene ``scene`` (an apartment, or the house / office ``building`` says), render ``params.frames``
    frames and write the ROS 2 MCAP log ``out_path``.

    ``progress(iterable, total)`` may wrap the block loop (e.g. ``StageContext.progress``).
    Memory is bounded by one block of ``params.render_block_frames`` frames. Returns summary figures.
    """
    from pipeline.ros2 import Ros2LogWriter

    t0 = time.perf_counter()
    rec = SimulatedRecording(scene, params, building=building)
    raycaster = SceneRaycaster(rec.gt, rec.intrinsics)
    gt = rec.gt
    metadata = {"generator": "zipon simulate", "scene": scene, "seed": str(gt.seed),
                "params": params.model_dump_json()}
    if building is not None:  # an apartment's log stays byte for byte what it was
        metadata["building"] = building.model_dump_json()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    n_blocks = -(-params.frames // params.render_block_frames)
    blocks = rec.blocks(raycaster)
    if progress is not None:
        blocks = progress(blocks, n_blocks)
    render_s = 0.0
    with Ros2LogWriter(out_path, intrinsics=rec.intrinsics, image_transport=params.image_transport,
                       pose_topic_kind=params.pose_topic_kind, with_instance=True, metadata=metadata) as writer:
        writer.attach_ground_truth(gt)
        next_pose = 0
        tb = time.perf_counter()
        for start, rgb, depth_mm, instance in blocks:
            render_s += time.perf_counter() - tb
            for i in range(len(rgb)):
                stamp = int(rec.frame_ns[start + i])
                while next_pose < len(rec.pose_ns) and rec.pose_ns[next_pose] <= stamp:  # time order
                    writer.write_pose(int(rec.pose_ns[next_pose]), rec.recorded_pose_T[next_pose])
                    next_pose += 1
                writer.write_frame(stamp, rgb[i], depth_mm[i], instance[i])
            tb = time.perf_counter()
        for k in range(next_pose, len(rec.pose_ns)):
            writer.write_pose(int(rec.pose_ns[k]), rec.recorded_pose_T[k])
    seconds = time.perf_counter() - t0
    summary = {
        "frames": params.frames, "poses": int(len(rec.pose_ns)), "actions": rec.actions,
        "rooms": len(gt.rooms), "objects": len(gt.objects), "classes": len({o.cls for o in gt.objects}),
        "rooms_visited": len(set(rec.visited)), "scene_seed": gt.seed,
        "render_seconds": round(render_s, 3), "seconds": round(seconds, 3),
        "bytes": out_path.stat().st_size,
    }
    if gt.floors:
        on = frame_floors(gt, rec.frame_T, params.camera_height_m)
        summary.update(floors=len(gt.floors), stairs=len(gt.stairs),
                       frames_per_floor=[int((on == f.id).sum()) for f in gt.floors])
    if building is not None:
        x0, x1, y0, y1 = gt.bounds_xy()
        summary.update(building=building.kind, extent_m=[round(x1 - x0, 2), round(y1 - y0, 2)])
    return summary
