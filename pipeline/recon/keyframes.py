"""Keyframes: which frames of a walk are worth fusing.

At 10-30 Hz consecutive frames see nearly the same surfaces. The rule of KinectFusion-style systems keeps a
frame (a keyframe) when, against the last keyframe, the camera

* moved farther than ``keyframe_translation_m`` (distance between the optical centres), or
* turned more than ``keyframe_rotation_deg`` (angle of the relative rotation), or
* sees enough that the last keyframe did not: more than ``keyframe_novel_fraction`` of its valid depth
  pixels (sampled every ``keyframe_pixel_stride`` pixels), put in the world and projected into the last
  keyframe, land outside its image, on a pixel without depth there, or more than ``keyframe_depth_tolerance``
  (a fraction of the depth) in front of or behind what the keyframe measured (a disocclusion).

The first frame with valid depth is a keyframe. The rule reads frames in index order and only the frame's own
pose and depth and the last keyframe's, so a selection depends on the data alone (not on workers or blocks).
Every frame is still ingested and stored; the reconstruction records the selection (``recon.zarr`` ``fused``
and attrs ``keyframes``) and the map stages may fuse only those frames (``maps.keyframes_only``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import Intrinsics, invert_pose

REASONS = ("first", "translation", "rotation", "novel_pixels")


@dataclass(frozen=True)
class KeyframeRule:
    """The thresholds of the rule (``reconstruct.keyframe_*``)."""

    translation_m: float
    rotation_deg: float
    novel_fraction: float | None  # None: the pixel test is off
    pixel_stride: int = 8
    depth_tolerance: float = 0.05

    @classmethod
    def from_params(cls, p) -> "KeyframeRule":
        """The rule of a :class:`pipeline.config.ReconstructParams`."""
        return cls(p.keyframe_translation_m, p.keyframe_rotation_deg, p.keyframe_novel_fraction,
                   p.keyframe_pixel_stride, p.keyframe_depth_tolerance)


def motion(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation in metres, rotation in degrees) between two ``4x4`` camera poses."""
    translation = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
    R = T_a[:3, :3].T @ T_b[:3, :3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return translation, float(np.degrees(np.arccos(cos)))


def novel_fraction(depth_mm: np.ndarray, T: np.ndarray, key_depth_mm: np.ndarray, T_key: np.ndarray,
                   intr: Intrinsics, stride: int, tolerance: float) -> float:
    """Fraction of the valid depth pixels of a frame (every ``stride``-th) that the keyframe did not see (see the
    module docstring); depth ``(H, W)`` uint16 mm, 0 = invalid, both at the resolution ``intr`` describes."""
    d = depth_mm[::stride, ::stride].astype(np.float64) * 1e-3
    v, u = np.nonzero(d > 0)
    if u.size == 0:
        return 0.0
    z = d[v, u]
    cam = np.stack([(u * stride - intr.cx) / intr.fx * z, (v * stride - intr.cy) / intr.fy * z, z], axis=1)
    T_rel = invert_pose(T_key) @ T  # this camera -> the keyframe's camera
    k = cam @ T_rel[:3, :3].T + T_rel[:3, 3]
    ahead = k[:, 2] > 1e-6
    zk = np.where(ahead, k[:, 2], 1.0)
    ku = np.rint(k[:, 0] / zk * intr.fx + intr.cx).astype(np.int64)
    kv = np.rint(k[:, 1] / zk * intr.fy + intr.cy).astype(np.int64)
    inside = ahead & (ku >= 0) & (ku < key_depth_mm.shape[1]) & (kv >= 0) & (kv < key_depth_mm.shape[0])
    seen_z = np.zeros(u.size)
    seen_z[inside] = key_depth_mm[kv[inside], ku[inside]] * 1e-3
    seen = inside & (seen_z > 0) & (np.abs(seen_z - k[:, 2]) <= tolerance * k[:, 2])
    return float(1.0 - seen.mean())


@dataclass
class KeyframeSelector:
    """Applies a :class:`KeyframeRule` to frames given in index order (:meth:`offer`)."""

    rule: KeyframeRule
    intrinsics: Intrinsics
    reasons: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REASONS, 0))
    _key: tuple[np.ndarray, np.ndarray] | None = None  # the last keyframe's (pose, depth)

    def offer(self, depth_mm: np.ndarray, T: np.ndarray) -> bool:
        """Whether this frame (pose ``T``, depth ``(H, W)`` uint16 mm) is a keyframe; if so it becomes the one the
        next frames are compared with."""
        reason = self._reason(depth_mm, T)
        if reason:
            self.reasons[reason] += 1
            self._key = (np.array(T, dtype=np.float64), depth_mm)
        return bool(reason)

    def _reason(self, depth_mm: np.ndarray, T: np.ndarray) -> str:
        if self._key is None:
            return "first"
        T_key, key_depth = self._key
        translation, rotation = motion(T_key, T)
        if translation > self.rule.translation_m:
            return "translation"
        if rotation > self.rule.rotation_deg:
            return "rotation"
        r = self.rule
        if r.novel_fraction is not None and novel_fraction(depth_mm, T, key_depth, T_key, self.intrinsics,
                                                           r.pixel_stride, r.depth_tolerance) > r.novel_fraction:
            return "novel_pixels"
        return ""


def select_by_motion(poses: np.ndarray, translation_m: float, rotation_deg: float) -> np.ndarray:
    """``(N,)`` bool keyframes of ``(N,4,4)`` poses by the motion tests alone (no depth needed)."""
    selector = KeyframeSelector(KeyframeRule(translation_m, rotation_deg, None), Intrinsics(1, 1, 0, 0, 1, 1))
    empty = np.zeros((1, 1), dtype=np.uint16)
    return np.array([selector.offer(empty, T) for T in poses], dtype=bool)
