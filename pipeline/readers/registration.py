"""Depth registered into the colour camera: a depth image on its own camera (frame, intrinsics) re-projected
into the colour camera's pixels, nearest surface kept (z-buffer).

RealSense and Kinect-style drivers publish depth on the depth imager (``/camera/depth/image_rect_raw``,
frame ``camera_depth_optical_frame``, its own K and size) a few centimetres from the colour imager.
Each valid depth pixel is back-projected with the depth K, moved by ``T_color_depth`` (the static tf
between the two optical frames), projected with the colour K to the nearest colour pixel, and the
smallest z wins where several land on one pixel. Colour pixels no depth pixel lands on stay invalid
(0): there is no interpolation across holes, so no depth is invented at occlusion edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import Intrinsics


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
                f"baseline ({t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}) m, z-buffer, holes left invalid")

    def __call__(self, depth: np.ndarray) -> np.ndarray:
        """``(Hd,Wd)`` uint16 mm or float metres (0/NaN/inf invalid) -> ``(Hc,Wc)`` of the same dtype."""
        d = self.depth
        if depth.shape != (d.height, d.width):
            return depth  # the matcher's size check names the topic and frame
        metric = depth.dtype == np.uint16
        z = depth.astype(np.float64) * (1e-3 if metric else 1.0)
        valid = np.isfinite(z) & (z > 0)
        v, u = np.nonzero(valid)
        z = z[v, u]
        pts = np.stack([(u - d.cx) / d.fx * z, (v - d.cy) / d.fy * z, z], axis=-1)
        R, t = self.T_color_depth[:3, :3], self.T_color_depth[:3, 3]
        pc = pts @ R.T + t
        c = self.color
        zc = pc[:, 2]
        front = zc > 1e-6
        pc, zc = pc[front], zc[front]
        uc = np.rint(pc[:, 0] / zc * c.fx + c.cx).astype(np.int64)
        vc = np.rint(pc[:, 1] / zc * c.fy + c.cy).astype(np.int64)
        inside = (uc >= 0) & (uc < c.width) & (vc >= 0) & (vc < c.height)
        flat, zc = vc[inside] * c.width + uc[inside], zc[inside]
        order = np.argsort(zc, kind="stable")  # nearest first: np.unique keeps the first of each pixel
        pixels, first = np.unique(flat[order], return_index=True)
        out = np.zeros(c.height * c.width, dtype=np.float64)
        out[pixels] = zc[order][first]
        if metric:
            return np.clip(np.rint(out * 1000.0), 0, 65535).astype(np.uint16).reshape(c.height, c.width)
        out[out == 0] = np.nan
        return out.astype(np.float32).reshape(c.height, c.width)
