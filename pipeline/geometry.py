"""Geometry conventions — the one module that owns frames, poses, intrinsics and the grid.

- World: right-handed, **z up**, metres. Camera: OpenCV optical (x right, y down, z forward).
- A pose is a 4x4 float64 ``T_world_camera`` (maps camera points into the world).
- Quaternions are ``(qx, qy, qz, qw)`` (ROS/TUM order) unless a name says otherwise.
- Top-down grid: ``rows x cols`` cells of ``cell_size_m``; row 0 is the north (max y) edge,
  col 0 the west (min x) edge, so a grid image is north-up without flipping.
  :class:`GridSpec` is the only place that maps world (x, y) <-> (row, col).

Importers call the converters here (Habitat y-up, OpenGL cameras) at the border; nothing
else converts between frames by hand.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from pipeline.errors import InputDataError

# Habitat world (y up, -z forward) -> zipon world (z up): (x, y, z)_hab -> (x, -z, y).
R_ZUP_FROM_HABITAT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
# OpenGL camera (x right, y up, -z forward) -> OpenCV optical: flip y and z.
R_GL_FROM_CV = np.diag([1.0, -1.0, -1.0])


# ----------------------------------------------------------------------------- poses

def pose_from_tq(t_xyz: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """Pose(s) from translations ``(...,3)`` and quaternions ``(...,4)`` (x, y, z, w) -> ``(...,4,4)``."""
    t_xyz = np.asarray(t_xyz, dtype=np.float64)
    q_xyzw = np.asarray(q_xyzw, dtype=np.float64)
    from scipy.spatial.transform import Rotation  # imported here: scipy.spatial costs ~0.5 s of every CLI start

    batch = t_xyz.shape[:-1]
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = Rotation.from_quat(q_xyzw.reshape(-1, 4)).as_matrix().reshape(batch + (3, 3))
    T[..., :3, 3] = t_xyz
    T[..., 3, 3] = 1.0
    return T


def pose_to_tq(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pose_from_tq`: ``(...,4,4)`` -> translation ``(...,3)``, quaternion xyzw ``(...,4)``."""
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, dtype=np.float64)
    batch = T.shape[:-2]
    q = Rotation.from_matrix(T[..., :3, :3].reshape(-1, 3, 3)).as_quat().reshape(batch + (4,))
    return T[..., :3, 3].copy(), q


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Rigid inverse of ``(...,4,4)`` poses."""
    R = T[..., :3, :3]
    Ti = np.zeros_like(T)
    Ti[..., :3, :3] = np.swapaxes(R, -1, -2)
    Ti[..., :3, 3] = -np.einsum("...ji,...j->...i", R, T[..., :3, 3])
    Ti[..., 3, 3] = 1.0
    return Ti


def rigid_error(T: np.ndarray) -> np.ndarray:
    """How far ``(...,4,4)`` is from a rigid transform (max abs deviation; inf for non-finite)."""
    T = np.asarray(T, dtype=np.float64)
    R = np.nan_to_num(T[..., :3, :3], nan=0.0, posinf=0.0, neginf=0.0)  # non-finite handled below
    eye = np.eye(3)
    ortho = np.abs(np.einsum("...ji,...jk->...ik", R, R) - eye).max(axis=(-1, -2))
    det = np.abs(np.linalg.det(R) - 1.0)
    bottom = np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    err = np.maximum(np.maximum(ortho, det), bottom)
    finite = np.isfinite(T).all(axis=(-1, -2))
    return np.where(finite, err, np.inf)


def check_rigid(T: np.ndarray, *, tol: float = 1e-4, path=None, topic=None, first_frame: int = 0) -> None:
    """Raise :class:`InputDataError` naming the first frame whose pose is NaN or not rigid."""
    err = rigid_error(np.asarray(T).reshape(-1, 4, 4))
    bad = np.flatnonzero(~(err <= tol))
    if bad.size:
        i = int(bad[0])
        what = "contains NaN/inf" if not np.isfinite(err[i]) else f"is not rigid (error {err[i]:.2e})"
        raise InputDataError(f"pose {what}", path=path, topic=topic, frame=first_frame + i,
                             expected=f"a finite rotation+translation (orthonormality within {tol})")


def nearest_rigid(T: np.ndarray, *, tol: float, path=None, frame: int | None = None) -> np.ndarray:
    """Re-orthonormalise a ``(4,4)`` pose read as a matrix: its rotation replaced by the nearest rotation (SVD).

    Poses stored as printed matrices (7-Scenes, Replica, ScanNet) are orthonormal only to their print
    precision (real 7-Scenes: ~2.5e-4). Within ``tol`` (:func:`rigid_error`) the pose is projected;
    beyond it, or NaN, :class:`InputDataError` names ``path`` and ``frame``.
    """
    T = np.asarray(T, dtype=np.float64)
    err = float(rigid_error(T))
    if not err <= tol:
        what = "contains NaN/inf" if not np.isfinite(err) else f"is not rigid (error {err:.2e})"
        raise InputDataError(f"pose {what}", path=path, frame=frame,
                             expected=f"a rotation orthonormal within ingest.pose_orthonormal_tol = {tol} "
                                      "(re-orthonormalised by SVD below it)")
    U, _, Vt = np.linalg.svd(T[:3, :3])
    out = np.eye(4)
    out[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out[:3, 3] = T[:3, 3]
    return out


def interpolate_poses(stamps_ns: np.ndarray, poses: np.ndarray, query_ns: np.ndarray) -> np.ndarray:
    """Poses at ``query_ns`` by linear translation and spherical rotation interpolation.

    ``stamps_ns`` ``(M,)`` sorted int64, ``poses`` ``(M,4,4)``; queries must lie in
    ``[stamps_ns[0], stamps_ns[-1]]``. Returns ``(Q,4,4)``.
    """
    from scipy.spatial.transform import Rotation, Slerp

    stamps = np.asarray(stamps_ns, dtype=np.int64)
    query = np.asarray(query_ns, dtype=np.int64)
    if len(stamps) == 1:
        return np.repeat(poses[:1], len(query), axis=0)
    # Relative seconds keep float64 precision for nanosecond stamps.
    t0 = stamps[0]
    ts = (stamps - t0).astype(np.float64) * 1e-9
    tq = (query - t0).astype(np.float64) * 1e-9
    rot = Slerp(ts, Rotation.from_matrix(poses[:, :3, :3]))(tq).as_matrix()
    trans = np.stack([np.interp(tq, ts, poses[:, i, 3]) for i in range(3)], axis=-1)
    out = np.zeros((len(query), 4, 4))
    out[:, :3, :3] = rot
    out[:, :3, 3] = trans
    out[:, 3, 3] = 1.0
    return out


def camera_pose_from_base(x: float, y: float, yaw: float, camera_height_m: float, pitch: float = 0.0) -> np.ndarray:
    """``T_world_camera`` for a forward-looking camera on a mobile base at (x, y) heading ``yaw``.

    ``yaw`` is measured counter-clockwise from world +x; ``pitch`` > 0 tilts the camera down.
    """
    forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    down = np.cross(forward, right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = right, down, forward
    T[:3, 3] = (x, y, camera_height_m)
    return T


def camera_yaw(T_world_camera: np.ndarray) -> np.ndarray:
    """Heading (rad, CCW from +x) of the optical axis projected on the floor, for ``(...,4,4)``."""
    z_axis = np.asarray(T_world_camera)[..., :3, 2]
    return np.arctan2(z_axis[..., 1], z_axis[..., 0])


def habitat_to_world(T_habitat_body: np.ndarray, camera_height_m: float) -> np.ndarray:
    """Habitat agent/base pose (y up, -z forward body) -> zipon ``T_world_camera``.

    The camera sits ``camera_height_m`` above the base along Habitat's +y, looking along the
    body's -z (an OpenGL-style frame), as in navchat's recordings.
    """
    T_hab_cam_gl = np.array(T_habitat_body, dtype=np.float64).copy()
    # The base only yaws about Habitat's +y, so "above the base" is world +y.
    T_hab_cam_gl[..., 1, 3] += camera_height_m
    out = np.zeros_like(T_hab_cam_gl)
    out[..., :3, :3] = R_ZUP_FROM_HABITAT @ T_hab_cam_gl[..., :3, :3] @ R_GL_FROM_CV
    out[..., :3, 3] = np.einsum("ij,...j->...i", R_ZUP_FROM_HABITAT, T_hab_cam_gl[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


# Source-world "up" directions an importer may state (ingest.world_up).
WORLD_UP_AXES = {"+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
                 "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


def R_zup_from_up(up) -> np.ndarray:
    """``(3,3)`` rotation from a source world whose up is ``up`` into zipon's z-up world.

    ``up``: an axis name of :data:`WORLD_UP_AXES` or a vector ``(3,)``. For an axis the rotation is a
    signed permutation: ``up`` -> +z, the first source axis across it (x, else y) -> +x, and +y
    completes a right-handed frame (so ``-y`` (7-Scenes) maps (x, y, z) -> (x, z, -y), ``+y``
    (Habitat) equals :data:`R_ZUP_FROM_HABITAT`). A vector is snapped to its nearest axis that way,
    then tilted onto +z by the smallest rotation.
    """
    u = np.asarray(WORLD_UP_AXES[up] if isinstance(up, str) else up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    axis = np.zeros(3)
    k = int(np.argmax(np.abs(u)))
    axis[k] = np.sign(u[k])
    x_new = np.eye(3)[0] if k != 0 else np.eye(3)[1]
    R_axis = np.stack([x_new, np.cross(axis, x_new), axis])
    v = R_axis @ u  # close to +z
    c = float(v[2])
    w = np.cross(v, [0.0, 0.0, 1.0])
    s = float(np.linalg.norm(w))
    if s < 1e-15:
        return R_axis
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]]) / s
    theta = np.arctan2(s, c)
    R_tilt = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)
    return R_tilt @ R_axis


def rotate_world(R_new_old: np.ndarray, T_old_camera: np.ndarray) -> np.ndarray:
    """Poses ``(...,4,4)`` re-expressed in a rotated world: ``T_new = [R 0; 0 1] @ T_old``."""
    T = np.asarray(T_old_camera, dtype=np.float64)
    out = T.copy()
    out[..., :3, :] = np.einsum("ij,...jk->...ik", R_new_old, T[..., :3, :])
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a ``(4,4)`` transform to ``(N,3)`` points."""
    return points @ T[:3, :3].T + T[:3, 3]


# ----------------------------------------------------------------------------- cameras

@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; no distortion."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> "Intrinsics":
        f = (width / 2.0) / np.tan(np.deg2rad(hfov_deg) / 2.0)
        return cls(f, f, width / 2.0, height / 2.0, width, height)

    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int) -> "Intrinsics":
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """Intrinsics of the same camera resampled to ``width x height`` (pixel-corner convention)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, width, height)

    def to_dict(self) -> dict:
        return {k: (int(v) if k in ("width", "height") else float(v)) for k, v in asdict(self).items()}


def backproject(depth_m: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Camera-frame points ``(H,W,3)`` from a metric depth image ``(H,W)`` (z-depth)."""
    h, w = depth_m.shape
    u = np.arange(w, dtype=np.float32)
    v = np.arange(h, dtype=np.float32)
    z = depth_m.astype(np.float32)
    x = (u[None, :] - intr.cx) / intr.fx * z
    y = (v[:, None] - intr.cy) / intr.fy * z
    return np.stack([x, y, z], axis=-1)


# ----------------------------------------------------------------------------- grid

@dataclass(frozen=True)
class GridSpec:
    """A north-up top-down grid: the only world (x, y) <-> (row, col) mapping.

    ``origin_xy`` is the world position of the north-west corner of cell (0, 0), i.e.
    ``(x_min, y_max)``. Cell (r, c) covers x in ``[x0 + c*s, x0 + (c+1)*s)`` and
    y in ``(y0 - (r+1)*s, y0 - r*s]``.
    """

    rows: int
    cols: int
    cell_size_m: float
    origin_xy: tuple[float, float]

    ORIENTATION = "north-up: row grows toward -y (south), col grows toward +x (east)"

    @classmethod
    def centered(cls, center_xy, rows: int, cols: int, cell_size_m: float) -> "GridSpec":
        cx, cy = float(center_xy[0]), float(center_xy[1])
        return cls(rows, cols, cell_size_m, (cx - cols * cell_size_m / 2.0, cy + rows * cell_size_m / 2.0))

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """``(...,2)`` world x, y -> ``(...,2)`` int64 (row, col); may be outside the grid."""
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor((xy[..., 0] - self.origin_xy[0]) / self.cell_size_m)
        row = np.floor((self.origin_xy[1] - xy[..., 1]) / self.cell_size_m)
        return np.stack([row, col], axis=-1).astype(np.int64)

    def cell_to_world(self, rc: np.ndarray) -> np.ndarray:
        """``(...,2)`` (row, col) -> ``(...,2)`` world x, y of the cell centres."""
        rc = np.asarray(rc, dtype=np.float64)
        x = self.origin_xy[0] + (rc[..., 1] + 0.5) * self.cell_size_m
        y = self.origin_xy[1] - (rc[..., 0] + 0.5) * self.cell_size_m
        return np.stack([x, y], axis=-1)

    def inside(self, rc: np.ndarray) -> np.ndarray:
        rc = np.asarray(rc)
        return (rc[..., 0] >= 0) & (rc[..., 0] < self.rows) & (rc[..., 1] >= 0) & (rc[..., 1] < self.cols)

    def holds(self, mask: np.ndarray, xy) -> bool:
        """Whether the world point ``xy`` lies on a True cell of ``mask`` (``(rows, cols)``, on this grid); False
        off the grid."""
        rc = self.world_to_cell(np.asarray(xy, np.float64)[:2])
        return bool(self.inside(rc) and mask[rc[0], rc[1]])

    @property
    def extent_xy(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` in metres."""
        x0, y1 = self.origin_xy
        return x0, x0 + self.cols * self.cell_size_m, y1 - self.rows * self.cell_size_m, y1

    def to_attrs(self) -> dict:
        return {
            "rows": int(self.rows),
            "cols": int(self.cols),
            "cell_size_m": float(self.cell_size_m),
            "origin_xy": [float(self.origin_xy[0]), float(self.origin_xy[1])],
            "orientation": self.ORIENTATION,
        }

    @classmethod
    def from_attrs(cls, attrs: dict) -> "GridSpec":
        return cls(int(attrs["rows"]), int(attrs["cols"]), float(attrs["cell_size_m"]), tuple(attrs["origin_xy"]))
