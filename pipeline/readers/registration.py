"""Depth registered into the colour camera: a depth image on its own camera (frame, intrinsics) re-projected
into the colour camera's pixels, nearest surface kept (z-buffer).

RealSense and Kinect-style drivers publish depth on the depth imager (``/camera/depth/image_rect_raw``,
frame ``camera_depth_optical_frame``, its own K and size) a few centimetres from the colour imager.
Each valid depth pixel's footprint -- its two corners (u -/+ 0.5, v -/+ 0.5) at its depth -- is
back-projected with the depth K, moved by ``T_color_depth`` (the static tf between the two optical
frames) and projected with the colour K; every colour pixel whose centre lies inside the projected
footprint (at most ``MAX_SPAN_PX`` a side), and always the pixel the depth pixel's centre lands in,
gets the point's colour-frame z; the smallest z wins where several land on one pixel (z-buffer).
Like librealsense's ``align``, this fills colour pixels denser than the depth pixels without
interpolating (and is exact when both cameras are the same); colour pixels no footprint covers
(occlusions, outside the depth view) stay invalid (0), so no depth is invented at occlusion edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import Intrinsics

MAX_SPAN_PX = 4  # a depth pixel's footprint fills at most this many colour pixels a side


@dataclass(frozen=True)
class DepthRegistration:
    """Depth camera ``depth`` -> colour camera ``color``; ``T_color_depth`` ``(4,4)`` maps depth-optical points
    into the colour optical frame."""

    depth: Intrinsics
    color: Intrinsics
    T_color_depth: np.ndarray

    def describe(self) -> str:
        t = self.T_color_depth[:3, 3]
        return (f"depth registered into the colour camera: {self.depth.width}x{self.depth.height} "
                f"(fx {self.depth.fx:.2f}) -> {self.color.width}x{self.color.height} (fx {self.color.fx:.2f}), "
                f"baseline ({t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}) m, pixel footprints, z-buffer")

    def __call__(self, depth: np.ndarray) -> np.ndarray:
        """``(Hd,Wd)`` uint16 mm or float metres (0/NaN/inf invalid) -> ``(Hc,Wc)`` of the same dtype."""
        d = self.depth
        if depth.shape != (d.height, d.width):
            return depth  # the matcher's size check names the topic and frame
        metric = depth.dtype == np.uint16
        z = depth.astype(np.float32) * np.float32(1e-3 if metric else 1.0)
        valid = np.isfinite(z) & (z > 0)
        v, u = np.nonzero(valid)
        z = z[v, u]
        R = self.T_color_depth[:3, :3].astype(np.float32)
        t = self.T_color_depth[:3, 3].astype(np.float32)
        c = self.color
        x, y = (u.astype(np.float32) - np.float32(d.cx)) * (z / np.float32(d.fx)), \
            (v.astype(np.float32) - np.float32(d.cy)) * (z / np.float32(d.fy))
        # the pixel centre in the colour frame, and how it moves per pixel of offset along both image axes;
        # component-wise, not (N,3) @ (3,3): a BLAS call on that shape is ~100x slower here
        centre = [R[i, 0] * x + R[i, 1] * y + R[i, 2] * z + t[i] for i in range(3)]
        step = [(R[i, 0] / np.float32(d.fx) + R[i, 1] / np.float32(d.fy)) * z for i in range(3)]

        def to_colour(offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            px, py, pz = (centre[i] + np.float32(offset) * step[i] for i in range(3)) if offset else centre
            zc = np.maximum(pz, np.float32(1e-9))
            return px / zc * np.float32(c.fx) + np.float32(c.cx), py / zc * np.float32(c.fy) + np.float32(c.cy), pz

        xa, ya, za = to_colour(-0.5)
        xb, yb, zb = to_colour(0.5)
        xc, yc, zc = to_colour(0.0)
        front = (za > 1e-6) & (zb > 1e-6) & (zc > 1e-6)
        # colour pixels whose centre lies in the footprint, and always the one the pixel centre lands in
        uc, vc = np.floor(xc[front] + 0.5).astype(np.int64), np.floor(yc[front] + 0.5).astype(np.int64)
        u0 = np.minimum(np.ceil(np.minimum(xa, xb)[front]).astype(np.int64), uc)
        u1 = np.maximum(np.ceil(np.maximum(xa, xb)[front]).astype(np.int64) - 1, uc)
        v0 = np.minimum(np.ceil(np.minimum(ya, yb)[front]).astype(np.int64), vc)
        v1 = np.maximum(np.ceil(np.maximum(ya, yb)[front]).astype(np.int64) - 1, vc)
        zc = zc[front]
        flat_out = np.full(c.height * c.width, np.inf, dtype=np.float32)
        span_u = int(min(MAX_SPAN_PX, (u1 - u0).max(initial=0) + 1))
        span_v = int(min(MAX_SPAN_PX, (v1 - v0).max(initial=0) + 1))
        for dv in range(span_v):
            for du in range(span_u):
                uu, vv = u0 + du, v0 + dv
                m = (uu <= u1) & (vv <= v1) & (uu >= 0) & (uu < c.width) & (vv >= 0) & (vv < c.height)
                np.minimum.at(flat_out, vv[m] * c.width + uu[m], zc[m])  # z-buffer: the nearest surface wins
        out = np.where(np.isfinite(flat_out), flat_out, np.float32(0)).astype(np.float64)
        if metric:
            return np.clip(np.rint(out * 1000.0), 0, 65535).astype(np.uint16).reshape(c.height, c.width)
        out[out == 0] = np.nan
        return out.astype(np.float32).reshape(c.height, c.width)
