"""Microsoft 7-Scenes sequence folders (``seq-XX``).

Layout: ``frame-NNNNNN.color.png`` (or ``.jpg``; 640x480 RGB), ``frame-NNNNNN.depth.png`` (uint16 mm,
65535 = invalid), ``frame-NNNNNN.pose.txt`` (4x4 camera-to-world, whitespace separated). There are
no timestamps: stamps are synthesised as ``N / ingest.folder_fps``. Intrinsics: the Kinect defaults
(585, 585, 320, 240) unless ``ingest.camera_override``. Note the dataset's depth is not registered
to colour (a known property of 7-Scenes); frames are stored as given.

Poses as released are orthonormal only to their print precision (~2.5e-4 on real sequences): each
is re-orthonormalised by SVD within ``ingest.pose_orthonormal_tol`` and refused beyond it, naming
the file. The world is the first Kinect frame, so y points down, as far as that frame was level:
``world_up`` is ``-y``, levelled on the floor when one is seen (:mod:`pipeline.readers.world_up`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.readers.base import (DEPTH, POSE, RGB, PoseLink, Reader, Sample, SourceInfo, frame_stamps_ns,
                                   native_intrinsics, read_depth16, read_image, read_pose_matrix, register)

SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
INVALID_DEPTH = 65535
_FRAME = re.compile(r"^frame-(\d+)\.color\.(png|jpg)$")


@register("7scenes")
class SevenScenesReader(Reader):
    """See the module doc."""

    world_up = "-y"
    world_up_levelled = True  # the first Kinect frame is level only as far as the person held it level

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.is_dir() and any(next(path.glob(f"frame-*.color.{e}"), None) for e in ("png", "jpg"))

    def open(self) -> SourceInfo:
        if not self.path.is_dir():
            raise InputDataError("not a folder", path=self.path, expected="a 7-Scenes sequence folder (seq-XX)")
        found = sorted((int(m.group(1)), m.group(2), len(m.group(1)))
                       for p in self.path.iterdir() if (m := _FRAME.match(p.name)))
        if not found:
            raise InputDataError("no frame-NNNNNN.color.png|jpg files", path=self.path,
                                 expected="a 7-Scenes sequence folder")
        exts = sorted({e for _, e, _ in found})
        if len(exts) > 1:
            raise InputDataError(f"colour frames in both {' and '.join(exts)}", path=self.path,
                                 expected="one colour format per sequence")
        ids, self.ext = [i for i, _, _ in found], exts[0]
        width = found[0][2]
        self.names = [f"frame-{i:0{width}d}" for i in ids]
        for k, name in enumerate(self.names):
            for suffix in (".depth.png", ".pose.txt"):
                if not (self.path / (name + suffix)).is_file():
                    raise InputDataError(f"{name}.color.png has no {suffix[1:]} file", path=self.path / (name + suffix),
                                         frame=k, expected="colour, depth and pose files for every frame")
        self.stamps = frame_stamps_ns(np.array(ids), self.params.folder_fps)
        o = self.params.camera_override
        fx, fy, cx, cy = (o.fx, o.fy, o.cx, o.cy) if o else SEVEN_SCENES_INTRINSICS
        intr, how = native_intrinsics(fx, fy, cx, cy, self.path / f"{self.names[0]}.color.{self.ext}",
                                      "ingest.camera_override" if o else "7-Scenes Kinect defaults")
        return SourceInfo(
            intrinsics=intr, has_instance=False, pose_chain=[PoseLink("world", "camera")],
            where={RGB: f"frame-*.color.{self.ext}", DEPTH: "frame-*.depth.png", "world->camera": "frame-*.pose.txt"},
            provenance={
                "frames": len(ids),
                "conversions": [
                    f"intrinsics: {how}",
                    f"stamps: synthesised as frame number / ingest.folder_fps ({self.params.folder_fps} Hz)",
                    f"depth: uint16 mm kept; {INVALID_DEPTH} (invalid) -> 0",
                    "pose: pose.txt 4x4 camera-to-world used as T_world_camera, re-orthonormalised by SVD "
                    f"(refused beyond ingest.pose_orthonormal_tol = {self.params.pose_orthonormal_tol}); "
                    "world = the first camera's frame (y down)",
                    "depth is not registered to colour in 7-Scenes; stored as given",
                ],
            },
        )

    def samples(self) -> Iterator[Sample]:
        for k, (name, stamp) in enumerate(zip(self.names, self.stamps.tolist())):
            base = self.path / name
            yield Sample(POSE, stamp, k, self._pose(base.with_name(name + ".pose.txt"), k), key="world->camera",
                         rigid=True)
            yield Sample(RGB, stamp, k, lambda f=base.with_name(f"{name}.color.{self.ext}"), k=k:
                         read_image(f, flags=cv2.IMREAD_COLOR, frame=k, what="colour"))
            yield Sample(DEPTH, stamp, k, lambda f=base.with_name(name + ".depth.png"), k=k: self._depth(f, k))

    def _pose(self, file: Path, k: int) -> np.ndarray:
        return read_pose_matrix(file, k, self.params.pose_orthonormal_tol)

    @staticmethod
    def _depth(file: Path, k: int) -> np.ndarray:
        img = read_depth16(file, k, "uint16 millimetres")
        return np.where(img == INVALID_DEPTH, 0, img).astype(np.uint16)
