"""World up at ingest: every reader's world turned so that +z is up (``ingest.world_up``).

zipon's world is z-up (docs: architecture, conventions); datasets are not: 7-Scenes' world is the first Kinect frame
(y down), Habitat's is y up. ``ingest.world_up`` states the source world's up axis:

- ``dataset`` (default): the reader's documented convention (:attr:`Reader.world_up`). Where that axis
  is up only approximately (:attr:`Reader.world_up_levelled`: 7-Scenes' world is its first camera,
  y down only as far as that camera was level), the floor found as for ``auto`` levels it when the
  floor's normal lies within ``LEVEL_MAX_TILT_DEG`` of the axis; otherwise the axis is used as is.
  Both outcomes are logged;
- ``+z``, ``-z``, ``+y``, ``-y``, ``+x``, ``-x``: stated by the user;
- ``auto``: gravity estimated as the normal of the dominant horizontal plane (the floor, or a table
  top in close-up sequences: both are level) in the first ``ingest.world_up_auto_frames`` frames.
  A prior tells floors from walls (:func:`gravity_priors`: the normal of the cameras' image-right
  axes, which stay level when there is little roll); the plane is fit by SVD to the points of the
  most populated height band, refined three times. What was chosen is logged.

The rotation comes from :func:`pipeline.geometry.R_zup_from_up` (the one module that owns frame
conventions) and is applied to every pose (:func:`pipeline.geometry.rotate_world`); it is stored
in ``frames.zarr`` attrs ``world_up`` with how it was obtained.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

import numpy as np

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameBlock
from pipeline.geometry import WORLD_UP_AXES, Intrinsics, R_zup_from_up, rotate_world

PRIOR_MAX_ANGLE_DEG = 35.0  # surface normals this close to the prior (level image-right axes) may be the floor
LEVEL_MAX_TILT_DEG = 30.0  # a documented axis is levelled on the floor when the floor lies this close to it
WIDE_PRIOR_ANGLE_DEG = 60.0  # ... to the cameras' mean image-up, which the pitch tilts (cameras that never turned)
PLANE_BAND_M = 0.03  # half-height of the band of points fit as the plane
MIN_PLANE_POINTS = 500
SAMPLE_COLUMNS = 96  # depth sampled on a grid about this many pixels wide


@dataclass(frozen=True)
class UpEstimate:
    """Gravity up in the source world, from the dominant horizontal plane."""

    up: np.ndarray  # (3,) unit vector, source world
    nearest_axis: str
    tilt_deg: float  # angle between ``up`` and ``nearest_axis``
    plane_points: int
    frames: int

    def describe(self) -> str:
        u = ", ".join(f"{v:+.4f}" for v in self.up)
        return (f"floor-plane normal ({u}) from {self.plane_points} points in {self.frames} frames: "
                f"nearest axis {self.nearest_axis}, tilted {self.tilt_deg:.2f} deg from it")


def _nearest_axis(u: np.ndarray) -> tuple[str, float]:
    name = max(WORLD_UP_AXES, key=lambda k: float(np.dot(WORLD_UP_AXES[k], u)))
    tilt = float(np.degrees(np.arccos(np.clip(np.dot(WORLD_UP_AXES[name], u), -1.0, 1.0))))
    return name, tilt


def gravity_priors(T_world_camera: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """First guesses of up ``(3,)``, each with how far (degrees) the floor normal may lie from it.

    - Cameras are mostly carried with little roll, so their image-right axes lie nearly level whatever
      their pitch: when the cameras turned (the right axes span a plane), up is that plane's normal
      (the smallest eigenvector of their scatter, sign from the mean image-up), within PRIOR_MAX_ANGLE_DEG.
    - The mean image-up, tilted by the unknown mean pitch (and right when the camera rolls on purpose,
      like TUM's rpy sequences): within WIDE_PRIOR_ANGLE_DEG.
    """
    up_img = (-T_world_camera[:, :3, 1]).mean(axis=0)  # image up (-y optical) averaged over the frames
    if len(T_world_camera) == 0 or np.linalg.norm(up_img) < 0.3:
        return []
    priors = []
    right = T_world_camera[:, :3, 0]
    evals, evecs = np.linalg.eigh(right.T @ right / len(right))
    if evals[1] > 4.0 * evals[0]:
        g = evecs[:, 0]
        priors.append((g if g @ up_img > 0 else -g, PRIOR_MAX_ANGLE_DEG))
    priors.append((up_img / np.linalg.norm(up_img), WIDE_PRIOR_ANGLE_DEG))
    return priors


def _surface_samples(depth_mm: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics, pick: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """World normals ``(M,3)`` (facing the camera) and points ``(M,3)`` of depth sampled on a coarse pixel grid."""
    stride = max(1, intr.width // SAMPLE_COLUMNS)
    z = depth_mm[pick, ::stride, ::stride].astype(np.float64) * 1e-3
    u = np.arange(0, intr.width, stride, dtype=np.float64)
    v = np.arange(0, intr.height, stride, dtype=np.float64)
    P = np.stack(np.broadcast_arrays((u[None, None, :] - intr.cx) / intr.fx * z,
                                     (v[None, :, None] - intr.cy) / intr.fy * z, z), axis=-1)  # (F,h,w,3)
    dx = P[:, :-1, 1:] - P[:, :-1, :-1]
    dy = P[:, 1:, :-1] - P[:, :-1, :-1]
    p = P[:, :-1, :-1]
    zc = z[:, :-1, :-1]
    step = 4.0 * stride * zc / min(intr.fx, intr.fy)  # neighbours farther apart: a depth edge, not a surface
    ok = ((zc > 0) & (z[:, :-1, 1:] > 0) & (z[:, 1:, :-1] > 0)
          & (np.linalg.norm(dx, axis=-1) < step) & (np.linalg.norm(dy, axis=-1) < step))
    normal = np.cross(dx, dy)
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    normal = np.where((np.einsum("...i,...i->...", normal, p) > 0)[..., None], -normal, normal)  # face the camera
    R, t = T_world_camera[pick, :3, :3], T_world_camera[pick, :3, 3]
    return (np.einsum("fij,fhwj->fhwi", R, normal)[ok],
            (np.einsum("fij,fhwj->fhwi", R, p) + t[:, None, None, :])[ok])


def _level_plane(n_w: np.ndarray, p_w: np.ndarray, prior: np.ndarray, cone_deg: float) -> tuple[np.ndarray, int]:
    """Normal of the densest level plane near ``prior`` and its point count (0 when there is none)."""
    cand = n_w @ prior > np.cos(np.radians(cone_deg))
    if cand.sum() < MIN_PLANE_POINTS:
        return prior, 0
    up = n_w[cand].mean(axis=0)
    up /= np.linalg.norm(up)
    for _ in range(3):  # mode of heights along the current up, plane fit, again with the refined up
        sel = n_w @ up > np.cos(np.radians(15.0))
        if sel.sum() < MIN_PLANE_POINTS:
            return up, 0
        h = p_w[sel] @ up
        bins = np.floor((h - h.min()) / 0.02).astype(np.int64)
        counts = np.convolve(np.bincount(bins), np.ones(3), mode="same")
        h0 = h.min() + (int(np.argmax(counts)) + 0.5) * 0.02
        pts = p_w[sel][np.abs(h - h0) < PLANE_BAND_M]
        if len(pts) < MIN_PLANE_POINTS:
            return up, 0
        normal_fit = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)[2][-1]
        up = normal_fit if normal_fit @ up > 0 else -normal_fit
    return up, len(pts)


def find_level_plane(depth_mm: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics, *, max_frames: int = 16
                     ) -> UpEstimate | str:
    """Up ``(3,)`` of the world of ``T_world_camera`` ``(N,4,4)`` from depth ``(N,H,W)`` uint16 mm: the plane
    with the most points among those found near each of :func:`gravity_priors`; or why there is none."""
    n = len(depth_mm)
    priors = gravity_priors(T_world_camera)
    if not priors:
        return "the cameras' image-up directions disagree, no prior for gravity"
    pick = np.unique(np.round(np.linspace(0, n - 1, min(n, max_frames))).astype(int))
    n_w, p_w = _surface_samples(depth_mm, T_world_camera, intr, pick)
    up, points = max((_level_plane(n_w, p_w, g, cone) for g, cone in priors), key=lambda r: r[1])
    if points == 0:
        return f"no level plane of {MIN_PLANE_POINTS}+ depth samples in the first {n} frames"
    axis, tilt = _nearest_axis(up)
    return UpEstimate(up=up, nearest_axis=axis, tilt_deg=tilt, plane_points=points, frames=len(pick))


def estimate_up(depth_mm: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics, *, source: str = "",
                max_frames: int = 16) -> UpEstimate:
    """:func:`find_level_plane`, raising :class:`InputDataError` when there is none (state the axis instead)."""
    found = find_level_plane(depth_mm, T_world_camera, intr, max_frames=max_frames)
    if isinstance(found, str):
        raise InputDataError(f"world_up auto: {found}", path=source, field="ingest.world_up",
                             expected="a level floor or table seen from above; or set ingest.world_up to the "
                                      "dataset's up axis")
    return found


class WorldUp:
    """The world-up conversion of one ingest: :meth:`apply` rotates the poses of every block."""

    def __init__(self, params: IngestParams, dataset_up: str, intrinsics: Intrinsics, *, levelled: bool = False,
                 source: str = "", log: Callable[[str], None] = print):
        self.setting = params.world_up
        self.auto_frames = params.world_up_auto_frames
        self.intrinsics, self.source, self.log = intrinsics, source, log
        self.estimate: UpEstimate | None = None
        self.level_note = ""
        self.source_up = dataset_up if self.setting == "dataset" else self.setting
        self.levelled = levelled and self.setting == "dataset"
        self.R = None if self.setting == "auto" else R_zup_from_up(self.source_up)

    @property
    def identity(self) -> bool:
        return self.setting != "auto" and self.source_up == "+z" and not self.levelled

    def _find_floor(self, pending: list[FrameBlock]) -> None:
        depth = np.concatenate([b.depth_mm for b in pending])[: self.auto_frames]
        poses = np.concatenate([b.T_world_camera for b in pending])[: self.auto_frames]
        if self.setting == "auto":
            self.estimate = estimate_up(depth, poses, self.intrinsics, source=self.source)
            self.R = R_zup_from_up(self.estimate.up)
            self.log(f"world_up auto: {self.estimate.describe()}; rotated onto +z")
            return
        est = find_level_plane(depth, poses, self.intrinsics)
        if isinstance(est, str):
            self.level_note = f"not levelled: {est}"
        elif est.nearest_axis == self.source_up and est.tilt_deg <= LEVEL_MAX_TILT_DEG:
            self.estimate, self.R = est, R_zup_from_up(est.up)
            self.level_note = f"levelled on the floor: {est.describe()}"
        else:
            self.level_note = (f"not levelled: the densest level plane ({est.describe()}) is not within "
                               f"{LEVEL_MAX_TILT_DEG} deg of {self.source_up}")
        self.log(f"world_up: {self.record()['how']}; rotated onto +z")

    def apply(self, blocks: Iterable[FrameBlock]) -> Iterator[FrameBlock]:
        blocks = iter(blocks)
        pending: list[FrameBlock] = []
        if self.R is None or self.levelled:  # hold the first frames back until the floor is found in them
            held = 0
            for b in blocks:
                pending.append(b)
                held += len(b)
                if held >= self.auto_frames:
                    break
            if pending:
                self._find_floor(pending)
        elif not self.identity:
            self.log(f"world_up: {self.record()['how']}; rotated onto +z")
        yield from self.rotated(itertools.chain(pending, blocks))

    def rotated(self, blocks: Iterable[FrameBlock]) -> Iterator[FrameBlock]:
        """``blocks`` with their poses rotated by the rotation already chosen (a scene's later logs take the
        first log's, so the scene has one world)."""
        for b in blocks:
            b.T_world_camera = rotate_world(self.R, b.T_world_camera)
            yield b

    def record(self) -> dict:
        """What goes into frames.zarr attrs ``world_up``."""
        rec = {"setting": self.setting,
               "source_up": self.source_up if self.setting != "auto" or self.estimate is None
               else self.estimate.up.tolist(),
               "R_zup_from_source": None if self.R is None else self.R.tolist()}
        if self.setting == "dataset":
            rec["how"] = f"the reader's documented convention: the dataset's world has {self.source_up} up"
            if self.level_note:
                rec["how"] += f", {self.level_note}"
        elif self.estimate is not None:
            rec["how"] = f"estimated: {self.estimate.describe()}"
        else:
            rec["how"] = f"stated by ingest.world_up: {self.source_up} up"
        if self.estimate is not None:
            rec["estimate"] = {"up": self.estimate.up.tolist(), "nearest_axis": self.estimate.nearest_axis,
                               "tilt_deg": self.estimate.tilt_deg, "plane_points": self.estimate.plane_points,
                               "frames": self.estimate.frames}
        return rec
