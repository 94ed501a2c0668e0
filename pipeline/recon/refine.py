"""Optional pose refinement for real logs: frame-to-model RGB-D odometry against the fused volume.

Each frame's pose is predicted from the previous *refined* pose and the *recorded* relative motion
(so corrections carry forward), the model is ray-cast at the prediction, and open3d's multi-scale
RGB-D odometry aligns the frame to that rendering (the pattern of open3d's dense SLAM). A result
with too few inliers, or that moves the frame more than ``refine_max_correction_m`` from the
prediction, is rejected and the prediction kept. Refined poses are written to ``recon.zarr``;
``frames.zarr`` is never modified.

open3d's odometry sums its normal equations with a parallel reduction whose float summation order
follows the thread schedule: run to run, poses would differ by up to millimetres (and every artifact
after them). The odometry therefore runs on one thread (:func:`_serial_open3d`), which sums in a fixed
order: the same frames give the same poses for any number of threads or workers.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager

import numpy as np
import open3d as o3d

from pipeline.config import ReconstructParams
from pipeline.geometry import Intrinsics, invert_pose

o3c = o3d.core
_MIN_FITNESS = 0.1  # fraction of frame pixels matched to the model (it is sparse early on)
_MIN_PYRAMID_PX = 60  # coarsest odometry level keeps at least this many pixels per side
_WARMUP_FRAMES = 3  # the first frames build the model at their recorded poses
_SERIAL = threading.Lock()  # open3d's thread limit is process-wide: one serial section at a time


@contextmanager
def _serial_open3d():
    """Run the enclosed open3d calls on one thread (reductions in a fixed order); the previous limit is restored."""
    with _SERIAL:
        before = o3d.utility.get_max_threads()
        o3d.utility.set_max_threads(1)
        try:
            yield
        finally:
            o3d.utility.set_max_threads(before)


class PoseRefiner:
    """Callable ``(volume, depth_mm, rgb, T_recorded, intr, index) -> T_refined`` for :func:`tsdf.fuse`."""

    def __init__(self, p: ReconstructParams):
        self.p = p
        # ray_cast logs every range-map reallocation at INFO/WARNING; they are expected here.
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        self.prev_recorded: np.ndarray | None = None
        self.prev_refined: np.ndarray | None = None
        self.n_seen = 0
        self.rejected: list[int] = []
        self.corrections_m: list[float] = []
        method = {"hybrid": o3d.t.pipelines.odometry.Method.Hybrid,
                  "point_to_plane": o3d.t.pipelines.odometry.Method.PointToPlane}
        self.method = method[p.refine_method]

    def __call__(self, volume, depth_mm: np.ndarray, rgb: np.ndarray, T_recorded: np.ndarray, intr: Intrinsics,
                 index: int) -> np.ndarray:
        if self.prev_refined is None:
            T_pred = T_recorded
        else:
            T_pred = self.prev_refined @ invert_pose(self.prev_recorded) @ T_recorded
        T = T_pred
        if self.n_seen >= _WARMUP_FRAMES:
            T = self._align(volume, depth_mm, rgb, T_pred, intr, index)
        self.n_seen += 1
        self.prev_recorded, self.prev_refined = T_recorded, T
        return T

    def _align(self, volume, depth_mm, rgb, T_pred, intr, index) -> np.ndarray:
        p = self.p
        K = o3c.Tensor(intr.K, o3c.float64)
        extrinsic = o3c.Tensor(invert_pose(T_pred), o3c.float64)
        trunc_mult = p.sdf_trunc_m / p.voxel_size_m
        depth = o3d.t.geometry.Image(o3c.Tensor(depth_mm))
        coords = volume.compute_unique_block_coordinates(depth, K, extrinsic, 1000.0, p.depth_max_m, trunc_mult)
        model = volume.ray_cast(coords, K, extrinsic, intr.width, intr.height, ["depth", "color"], 1000.0,
                                p.depth_min_m, p.depth_max_m, p.min_weight, trunc_mult, 8)
        target = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(model["color"]), o3d.t.geometry.Image(model["depth"]))
        color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0))
        source = o3d.t.geometry.RGBDImage(color, depth)  # uint16 mm: odometry applies depth_scale
        levels = max(1, int(np.log2(min(intr.width, intr.height) / _MIN_PYRAMID_PX)) + 1)
        try:
            with _serial_open3d():
                res = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                    source, target, K, o3c.Tensor(np.eye(4)), 1000.0, p.depth_max_m,
                    [o3d.t.pipelines.odometry.OdometryConvergenceCriteria(8)] * levels, self.method)
        except RuntimeError:  # open3d raises when too few correspondences are found
            self.rejected.append(index)
            return T_pred
        T_target_source = res.transformation.numpy()
        correction = float(np.linalg.norm(T_target_source[:3, 3]))
        if res.fitness < _MIN_FITNESS or correction > p.refine_max_correction_m or not np.isfinite(T_target_source).all():
            self.rejected.append(index)
            return T_pred
        self.corrections_m.append(correction)
        return T_pred @ T_target_source

    def summary(self) -> dict:
        c = np.asarray(self.corrections_m) if self.corrections_m else np.zeros(1)
        return {"frames_aligned": len(self.corrections_m), "frames_rejected": len(self.rejected),
                "rejected": self.rejected[:100], "median_step_correction_m": round(float(np.median(c)), 5),
                "max_step_correction_m": round(float(c.max()), 5)}
