"""Ego views ray-cast from the RECONSTRUCTED mesh (``recon_mesh.ply``) at the agent's pose.

open3d's ``RaycastingScene`` casts one ray per pixel centre (camera direction ``((u-cx)/fx,
(v-cy)/fy, 1)``, so the hit distance is the z-depth, as in :mod:`pipeline.sim.raycast`); colour is
the barycentric mix of the hit triangle's vertex colours. For simulated scenes an instance image
is added by looking up which ground-truth object part box contains each hit point (within
``tolerance_m``): only the diagnostic ``oracle`` encoder reads it. Line of sight is the routes
module's :class:`pipeline.nav.region.MeshSight` on the same ray-casting scene (:meth:`EgoRenderer.sight`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import Intrinsics, camera_pose_from_base

INVALID = np.uint32(0xFFFFFFFF)


@dataclass
class EgoView:
    """One rendered view: ``rgb`` (H,W,3) uint8, ``depth_m`` (H,W) float32 (0 = no hit),
    ``points`` (H,W,3) float32 world hit points, ``hit`` (H,W) bool, ``instance`` (H,W) uint16 or None."""

    rgb: np.ndarray
    depth_m: np.ndarray
    points: np.ndarray
    hit: np.ndarray
    instance: np.ndarray | None
    pose: tuple[float, float, float]


class EgoRenderer:
    """Renders ``size`` = (height, width) views with a ``hfov_deg`` pinhole at ``camera_height_m`` above the floor."""

    def __init__(self, mesh_path, *, floor_z: float, camera_height_m: float, size: tuple[int, int] = (24, 32),
                 hfov_deg: float = 90.0, gt=None, tolerance_m: float = 0.05):
        import open3d as o3d

        mesh = o3d.io.read_triangle_mesh(str(mesh_path))
        self.vertices = np.asarray(mesh.vertices, dtype=np.float32)
        self.triangles = np.asarray(mesh.triangles, dtype=np.int64)
        cols = np.asarray(mesh.vertex_colors, dtype=np.float32)
        self.colors = cols if len(cols) == len(self.vertices) else np.full_like(self.vertices, 0.5)
        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        if len(self.triangles):
            self.scene.add_triangles(o3d.core.Tensor(self.vertices), o3d.core.Tensor(self.triangles.astype(np.uint32)))
        h, w = size
        self.intrinsics = Intrinsics.from_hfov(w, h, hfov_deg)
        K = self.intrinsics
        u, v = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)
        self.dirs_cam = np.stack(np.broadcast_arrays((u[None, :] - K.cx) / K.fx, (v[:, None] - K.cy) / K.fy,
                                                     np.ones((h, w))), axis=-1).astype(np.float32)
        self.cam_z = float(floor_z) + float(camera_height_m)
        self.floor_z = float(floor_z)
        self.tolerance = float(tolerance_m)
        self.boxes = None
        if gt is not None:
            parts = [(o.id, p) for o in gt.objects for p in o.parts]
            if parts:
                self.boxes = (np.array([p.min for _, p in parts], np.float32), np.array([p.max for _, p in parts], np.float32),
                              np.array([i for i, _ in parts], np.uint16),
                              np.array([np.prod(np.subtract(p.max, p.min)) for _, p in parts], np.float32))

    def on_floor(self, floor_z: float, camera_height_m: float) -> "EgoRenderer":
        """This renderer (the same mesh, ray-casting scene and boxes) with the camera ``camera_height_m`` above the
        floor at ``floor_z``: a building's other floors."""
        import copy

        other = copy.copy(self)
        other.floor_z, other.cam_z = float(floor_z), float(floor_z) + float(camera_height_m)
        return other

    def sight(self, grid):
        """The shared line-of-sight test (:class:`pipeline.nav.region.MeshSight`) on this mesh and camera."""
        from pipeline.nav.region import MeshSight

        return MeshSight(self.scene, cam_z=self.cam_z, floor_z=self.floor_z, grid=grid)

    def T_world_camera(self, pose) -> np.ndarray:
        x, y, yaw = (float(v) for v in pose)
        T = camera_pose_from_base(x, y, yaw, 0.0)
        T[2, 3] = self.cam_z
        return T

    def render(self, pose) -> EgoView:
        """The view from ``pose`` = (x, y, yaw) (world metres, radians)."""
        T = self.T_world_camera(pose)
        h, w = self.dirs_cam.shape[:2]
        rays = np.empty((h, w, 6), np.float32)
        rays[..., :3] = T[:3, 3].astype(np.float32)
        rays[..., 3:] = self.dirs_cam @ T[:3, :3].T.astype(np.float32)
        hits = self.scene.cast_rays(self._o3d.core.Tensor(rays))
        t = hits["t_hit"].numpy()
        prim = hits["primitive_ids"].numpy()
        hit = (prim != INVALID) & np.isfinite(t)
        uv = hits["primitive_uvs"].numpy()
        rgb = np.zeros((h, w, 3), np.uint8)
        if hit.any():
            tri = self.triangles[prim[hit].astype(np.int64)]
            bu, bv = uv[hit, 0:1], uv[hit, 1:2]
            col = self.colors[tri[:, 0]] * (1 - bu - bv) + self.colors[tri[:, 1]] * bu + self.colors[tri[:, 2]] * bv
            rgb[hit] = np.clip(col * 255.0 + 0.5, 0, 255).astype(np.uint8)
        depth = np.where(hit, t, 0.0).astype(np.float32)
        points = rays[..., :3] + rays[..., 3:] * np.where(hit, t, 0.0)[..., None]
        instance = self._instances(points, hit) if self.boxes is not None else None
        return EgoView(rgb, depth, points.astype(np.float32), hit, instance, tuple(float(v) for v in pose))

    def _instances(self, points: np.ndarray, hit: np.ndarray) -> np.ndarray:
        """``(H,W)`` uint16 id of the smallest GT part box containing each hit point (0 = none)."""
        lo, hi, ids, vol = self.boxes
        p = points[hit]
        tol = self.tolerance
        if len(p):  # only boxes overlapping the hit points' bounding box can hold one (a view sees a few rooms' parts)
            near = np.flatnonzero(((lo - tol) <= p.max(axis=0)).all(axis=1) & ((hi + tol) >= p.min(axis=0)).all(axis=1))
            lo, hi, ids, vol = lo[near], hi[near], ids[near], vol[near]
        if not len(p) or not len(lo):
            return np.zeros(hit.shape, np.uint16)
        inside = ((p[:, None, :] >= lo[None] - tol) & (p[:, None, :] <= hi[None] + tol)).all(axis=2)  # (N,M)
        cost = np.where(inside, vol[None], np.inf)
        k = np.argmin(cost, axis=1)
        out = np.zeros(hit.shape, np.uint16)
        out[hit] = np.where(np.isfinite(cost[np.arange(len(p)), k]), ids[k], 0)
        return out
