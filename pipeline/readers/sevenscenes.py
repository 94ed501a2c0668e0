"""Microsoft 7-Scenes sequence folders (``seq-XX``).

Layout: ``frame-NNNNNN.color.png`` (640x480 RGB), ``frame-NNNNNN.depth.png`` (uint16 mm,
65535 = invalid), ``frame-NNNNNN.pose.txt`` (4x4 camera-to-world, whitespace separated). There are
no timestamps: stamps are synthesised as ``N / ingest.folder_fps``. Intrinsics: the Kinect defaults
(585, 585, 320, 240) unless ``ingest.camera_override``. Note the dataset's depth is not registered
to colour (a known property of 7-Scenes); frames are stored as given.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.readers.base import (DEPTH, POSE, RGB, PoseLink, Reader, Sample, SourceInfo, frame_stamps_ns,
                                   native_intrinsics, read_depth16, read_image, register)

SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
INVALID_DEPTH = 65535
_FRAME = re.compile(r"^frame-(\d+)\.color\.png$")


@register("7scenes")
class SevenScenesReader(Reader):
    """See the module doc."""

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.is_dir() and next(path.glob("frame-*.color.png"), None) is not None

    def open(self) -> SourceInfo:
        ids = sorted(int(m.group(1)) for p in self.path.iterdir() if (m := _FRAME.match(p.name)))
        if not ids:
            raise InputDataError("no frame-NNNNNN.color.png files", path=self.path,
                                 expected="a 7-Scenes sequence folder")
        width = len(next(self.path.glob("frame-*.color.png")).name) - len("frame-.color.png")
        self.names = [f"frame-{i:0{width}d}" for i in ids]
        for k, name in enumerate(self.names):
            for suffix in (".depth.png", ".pose.txt"):
                if not (self.path / (name + suffix)).is_file():
                    raise InputDataError(f"{name}.color.png has no {suffix[1:]} file", path=self.path / (name + suffix),
                                         frame=k, expected="colour, depth and pose files for every frame")
        self.stamps = frame_stamps_ns(np.array(ids), self.params.folder_fps)
        o = self.params.camera_override
        fx, fy, cx, cy = (o.fx, o.fy, o.cx, o.cy) if o else SEVEN_SCENES_INTRINSICS
        intr, how = native_intrinsics(fx, fy, cx, cy, self.path / f"{self.names[0]}.color.png",
                                      "ingest.camera_override" if o else "7-Scenes Kinect defaults")
        return SourceInfo(
            intrinsics=intr, has_instance=False, pose_chain=[PoseLink("world", "camera")],
            where={RGB: "frame-*.color.png", DEPTH: "frame-*.depth.png", "world->camera": "frame-*.pose.txt"},
            provenance={
                "frames": len(ids),
                "conversions": [
                    f"intrinsics: {how}",
                    f"stamps: synthesised as frame number / ingest.folder_fps ({self.params.folder_fps} Hz)",
                    f"depth: uint16 mm kept; {INVALID_DEPTH} (invalid) -> 0",
                    "pose: pose.txt 4x4 camera-to-world used as T_world_camera; world = the dataset's frame",
                    "depth is not registered to colour in 7-Scenes; stored as given",
                ],
            },
        )

    def samples(self) -> Iterator[Sample]:
        for k, (name, stamp) in enumerate(zip(self.names, self.stamps.tolist())):
            base = self.path / name
            yield Sample(POSE, stamp, k, self._pose(base.with_name(name + ".pose.txt"), k), key="world->camera")
            yield Sample(RGB, stamp, k, lambda f=base.with_name(name + ".color.png"), k=k:
                         read_image(f, flags=cv2.IMREAD_COLOR, frame=k, what="colour"))
            yield Sample(DEPTH, stamp, k, lambda f=base.with_name(name + ".depth.png"), k=k: self._depth(f, k))

    @staticmethod
    def _pose(file: Path, k: int) -> np.ndarray:
        try:
            T = np.loadtxt(file, dtype=np.float64)
        except ValueError as err:
            raise InputDataError(f"pose is not numeric ({err})", path=file, frame=k, expected="a 4x4 matrix") from None
        if T.shape != (4, 4):
            raise InputDataError(f"pose has shape {T.shape}", path=file, frame=k, expected="a 4x4 matrix")
        return T

    @staticmethod
    def _depth(file: Path, k: int) -> np.ndarray:
        img = read_depth16(file, k, "uint16 millimetres")
        return np.where(img == INVALID_DEPTH, 0, img).astype(np.uint16)
