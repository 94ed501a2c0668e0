"""Our own per-point reference of VLMaps' fusion loop, for ``bench_maps.py`` (not used by the pipeline).

VLMaps (``vlmaps/map/vlmap_builder.py``, ``create_mobile_base_map``) back-projects each frame's
depth and moves it to the world with one numpy product per FRAME, then runs a Python loop over
the points. Per point it: bins the world point into (row, col, height); drops it when out of range;
projects the camera point with the image's camera matrix (3x3 product, divide, round) and reads
its colour; projects it again with the feature map's camera matrix; keeps the colour of the
highest point per column (colour/height map); computes the distance weight
``alpha = exp(-|p_cam|^2 / (2 * 0.6))``; checks the feature pixel is inside the feature map; reads the
``(D,)`` feature from the ``(1, D, h, w)`` array; looks up the voxel's row in a dense
``(rows, cols, levels)`` int32 id lattice and either starts a new row (doubling the storage when
full) or updates the running means ``feat = (feat * w + f * alpha) / (w + alpha)`` (D floats) and
``rgb`` likewise, then ``w += alpha``.

This module does the same work per point, written from that description in plain Python + numpy,
with zipon's grid/level convention (:class:`~pipeline.maps.fusion.Lattice`) so its voxels can be
compared one to one with :class:`~pipeline.maps.fusion.VoxelAccumulator` fed the same points and
weights (``sigma^2 = 0.6``, i.e. ``sigma_m = sqrt(0.6)``).

It is a re-implementation, not VLMaps' code: ``bench_maps.py --vlmaps-src`` runs VLMaps' real builder on the same
frames (:mod:`benchmarks.vlmaps_real`) and prints both per-point costs and their ratio (``vlmaps_loop_over_real``);
quote the real figure.
"""

from __future__ import annotations

import math
import time

import numpy as np

from pipeline.geometry import Intrinsics, backproject
from pipeline.maps.fusion import Lattice

SIGMA_SQ = 0.6  # VLMaps' constant: alpha = exp(-|p|^2 / (2 * 0.6))


class VLMapsLoop:
    """Per-voxel running means over a Python loop, VLMaps-style (see the module docstring)."""

    def __init__(self, lattice: Lattice, dim: int, capacity: int = 16384):
        g = lattice.grid
        self.lattice, self.dim = lattice, dim
        self.occupied = -np.ones((g.rows, g.cols, lattice.levels), dtype=np.int32)
        self.feat = np.zeros((capacity, dim), dtype=np.float32)
        self.rgb = np.zeros((capacity, 3), dtype=np.float32)
        self.weight = np.zeros(capacity, dtype=np.float32)
        self.pos = np.zeros((capacity, 3), dtype=np.int32)
        self.height = np.full((g.rows, g.cols), -100, dtype=np.int32)
        self.color = np.zeros((g.rows, g.cols, 3), dtype=np.uint8)
        self.n = 0
        self.points_seen = 0

    def _reserve(self) -> None:
        cap = self.feat.shape[0]
        self.feat = np.concatenate([self.feat, np.zeros((cap, self.dim), np.float32)])
        self.rgb = np.concatenate([self.rgb, np.zeros((cap, 3), np.float32)])
        self.weight = np.concatenate([self.weight, np.zeros(cap, np.float32)])
        self.pos = np.concatenate([self.pos, np.zeros((cap, 3), np.int32)])

    def add_frame(self, depth_m: np.ndarray, T_world_camera: np.ndarray, feat_intr: Intrinsics, rgb: np.ndarray,
                  rgb_intr: Intrinsics, pix_feats: np.ndarray, *, depth_min_m: float, depth_max_m: float) -> int:
        """Fuse one frame; ``depth_m`` ``(h,w)`` at the feature resolution, ``pix_feats`` ``(1,D,h,w)`` float32,
        ``rgb`` ``(H,W,3)`` uint8. Returns the number of points looped over (valid depth)."""
        lat, g = self.lattice, self.lattice.grid
        # per frame, vectorized (as VLMaps does): back-projection, depth mask, camera -> world
        pc = backproject(depth_m, feat_intr).reshape(-1, 3)
        z = depth_m.reshape(-1)
        pc = pc[(z >= depth_min_m) & (z <= depth_max_m)]
        pc_global = pc @ T_world_camera[:3, :3].T + T_world_camera[:3, 3]
        K_rgb = np.array([[rgb_intr.fx, 0, rgb_intr.cx], [0, rgb_intr.fy, rgb_intr.cy], [0, 0, 1]])
        K_feat = np.array([[feat_intr.fx, 0, feat_intr.cx], [0, feat_intr.fy, feat_intr.cy], [0, 0, 1]])
        x0, y0, cs = g.origin_xy[0], g.origin_xy[1], g.cell_size_m
        z0, lh = lat.floor_z + lat.min_height_m, lat.level_height_m
        rows, cols, levels = g.rows, g.cols, lat.levels
        fh, fw = pix_feats.shape[2], pix_feats.shape[3]
        for p, p_local in zip(pc_global, pc):
            # grid id of the world point
            row = int(math.floor((y0 - p[1]) / cs))
            col = int(math.floor((p[0] - x0) / cs))
            h = int(math.floor((p[2] - z0) / lh))
            if col >= cols or row >= rows or h >= levels or col < 0 or row < 0 or h < 0:
                continue
            # colour: project into the image
            q = K_rgb @ p_local.reshape(3, 1)
            q = q / q[2, 0]
            px, py = int(q[0, 0] + 0.5), int(q[1, 0] + 0.5)
            rgb_v = rgb[min(py, rgb.shape[0] - 1), min(px, rgb.shape[1] - 1), :]
            # feature pixel: project into the feature map
            q = K_feat @ p_local.reshape(3, 1)
            q = q / q[2, 0]
            px, py = int(q[0, 0] + 0.5), int(q[1, 0] + 0.5)
            if h > self.height[row, col]:
                self.height[row, col] = h
                self.color[row, col, :] = rgb_v
            if self.n >= self.feat.shape[0]:
                self._reserve()
            alpha = np.exp(-np.sum(np.square(p_local)) / (2 * SIGMA_SQ))
            if not (px < 0 or py < 0 or px >= fw or py >= fh):
                f = pix_feats[0, :, py, px]
                vid = self.occupied[row, col, h]
                if vid == -1:
                    # VLMaps stores f * alpha here, which weighs a voxel's first point by alpha^2 in its
                    # mean; we store the mean of one point (f) so the result is the weighted mean
                    # the vectorized fusion computes. Same work per point.
                    self.occupied[row, col, h] = self.n
                    self.feat[self.n] = f.flatten()
                    self.rgb[self.n] = rgb_v
                    self.weight[self.n] += alpha
                    self.pos[self.n] = [row, col, h]
                    self.n += 1
                else:
                    w = self.weight[vid]
                    self.feat[vid] = (self.feat[vid] * w + f.flatten() * alpha) / (w + alpha)
                    self.rgb[vid] = (self.rgb[vid] * w + rgb_v * alpha) / (w + alpha)
                    self.weight[vid] += alpha
        self.points_seen += len(pc)
        return len(pc)

    def voxels(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flat cell ``(M,)``, level ``(M,)`` and L2-normalised features ``(M,D)``, sorted by (level, cell)."""
        pos = self.pos[: self.n]
        cell = pos[:, 0].astype(np.int64) * self.lattice.grid.cols + pos[:, 1]
        order = np.lexsort((cell, pos[:, 2]))
        f = self.feat[: self.n][order]
        return cell[order], pos[order, 2].astype(np.int64), f / np.linalg.norm(f, axis=1, keepdims=True)


def time_loop(lattice: Lattice, depth: np.ndarray, poses: np.ndarray, feat_intr: Intrinsics, rgb: np.ndarray,
              rgb_intr: Intrinsics, feats_bhwd: np.ndarray, *, depth_min_m: float, depth_max_m: float,
              min_points: int) -> tuple[VLMapsLoop, float, int, int, float]:
    """Loop over WHOLE frames until at least ``min_points`` points; returns (loop, seconds, points, frames,
    cpu_seconds): wall and CPU time of this process in :meth:`VLMapsLoop.add_frame` alone.

    ``feats_bhwd`` ``(B,h,w,D)`` is cycled over the frames like the vectorized benchmark does; the
    conversion to LSeg's ``(1,D,h,w)`` layout is not timed.
    """
    loop = VLMapsLoop(lattice, feats_bhwd.shape[-1])
    seconds, cpu_seconds, points, frames = 0.0, 0.0, 0, 0
    for b in range(len(depth)):
        if points >= min_points:
            break
        pix = np.ascontiguousarray(feats_bhwd[b % len(feats_bhwd)].transpose(2, 0, 1))[None]
        t0, c0 = time.perf_counter(), time.process_time()
        points += loop.add_frame(depth[b], poses[b], feat_intr, rgb[b % len(rgb)], rgb_intr, pix,
                                 depth_min_m=depth_min_m, depth_max_m=depth_max_m)
        seconds += time.perf_counter() - t0
        cpu_seconds += time.process_time() - c0
        frames += 1
    return loop, seconds, points, frames, cpu_seconds
