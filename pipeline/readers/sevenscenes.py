"""Microsoft 7-Scenes sequence folders (``seq-XX``).

Layout: ``frame-NNNNNN.color.png`` (or ``.jpg``; 640x480 RGB), ``frame-NNNNNN.depth.png`` (uint16 mm,
65535 = invalid), ``frame-NNNNNN.pose.txt`` (4x4 camera-to-world, whitespace separated). There are
no timestamps: stamps are synthesised as ``N / ingest.folder_fps``. Intrinsics: ``camera-intrinsics.txt``
where the layout ships one (3DMatch keeps its sequences in the 7-Scenes layout with the file in the scene
folder above ``seq-XX``; the TSDF-fusion demo data beside the frames): three rows of three numbers, the
pinhole matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` for the images as stored, looked up in the
sequence folder, then its parent; its values are recorded in the frames' attrs (``provenance``). Without
the file: the Kinect defaults (585, 585, 320, 240). ``ingest.camera_override`` replaces either. Note the dataset's depth is not registered
to colour (a known property of 7-Scenes); frames are stored as given.

Poses as released are orthonormal only to their print precision (~2.5e-4 on real sequences): each
is re-orthonormalised by SVD within ``ingest.pose_orthonormal_tol`` and refused beyond it, naming
the file. The world is the first Kinect frame, so y points down, as far as that frame was level:
``world_up`` is ``-y``, levelled on the floor when one is seen (:mod:`pipeline.readers.world_up`).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics
from pipeline.readers.base import (DEPTH, POSE, RGB, Opened, PoseLink, Reader, Sample, SourceInfo, frame_stamps_ns,
                                   native_intrinsics, read_depth16, read_image, read_pose_matrix)

SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
INTRINSICS_FILE = "camera-intrinsics.txt"
_K_EXPECTED = "3 rows of 3 numbers: fx 0 cx / 0 fy cy / 0 0 1, fx and fy > 0, (cx, cy) inside the image"
INVALID_DEPTH = 65535
_FRAME = re.compile(r"^frame-(\d+)\.color\.(png|jpg)$")


def camera_intrinsics_file(file: Path, first_image: Path) -> tuple[Intrinsics, np.ndarray]:
    """``camera-intrinsics.txt`` -> intrinsics at the size of ``first_image``, and the matrix as read.
    Anything but a 3x3 pinhole matrix (finite, no skew, last row 0 0 1, positive focal lengths, principal
    point inside the image) raises :class:`InputDataError` naming the file."""
    if file.stat().st_size > 4096:
        raise InputDataError(f"file is {file.stat().st_size} bytes", path=file, expected=_K_EXPECTED)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file: its shape says so below
            K = np.loadtxt(file, dtype=np.float64, ndmin=2)
    except ValueError as err:
        why = str(err).split(";")[0]  # numpy's own advice after the ';' (usecols) does not apply to this file
        raise InputDataError(f"camera matrix is not numeric ({why})", path=file, expected=_K_EXPECTED) from None
    if K.shape != (3, 3):
        raise InputDataError(f"camera matrix has shape {K.shape}", path=file, expected=_K_EXPECTED)
    if not np.isfinite(K).all():
        raise InputDataError("camera matrix holds NaN or inf", path=file, expected=_K_EXPECTED)
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
        raise InputDataError(f"not a pinhole camera matrix: {K.tolist()}", path=file, expected=_K_EXPECTED)
    img = read_image(first_image, flags=cv2.IMREAD_COLOR, frame=0, what="colour")
    h, w = img.shape[:2]
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    if fx <= 0 or fy <= 0 or not (0 < cx < w and 0 < cy < h):
        raise InputDataError(f"fx {fx}, fy {fy}, cx {cx}, cy {cy} do not fit {first_image.name} ({w}x{h})",
                             path=file, expected=_K_EXPECTED)
    return Intrinsics(fx, fy, cx, cy, w, h), K


@dataclass(frozen=True)
class SevenScenesFrames:
    """The opened sequence: each frame's file stem (``frame-NNNNNN``) and stamp, and the colour files' extension."""

    names: list[str]
    stamps: np.ndarray
    ext: str


class SevenScenesReader(Reader):
    """See the module doc."""

    name = "7scenes"
    layout = "a 7-Scenes folder (frame-*.color.png)"

    world_up = "-y"
    world_up_levelled = True  # the first Kinect frame is level only as far as the person held it level

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.is_dir() and any(next(path.glob(f"frame-*.color.{e}"), None) for e in ("png", "jpg"))

    def open(self) -> Opened[SevenScenesFrames]:
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
        ids, ext = [i for i, _, _ in found], exts[0]
        width = found[0][2]
        names = [f"frame-{i:0{width}d}" for i in ids]
        for k, name in enumerate(names):
            for suffix in (".depth.png", ".pose.txt"):
                if not (self.path / (name + suffix)).is_file():
                    raise InputDataError(f"{name}.color.png has no {suffix[1:]} file", path=self.path / (name + suffix),
                                         frame=k, expected="colour, depth and pose files for every frame")
        o = self.params.camera_override
        first = self.path / f"{names[0]}.color.{ext}"
        k_file = next((f for f in (self.path / INTRINSICS_FILE, self.path.parent / INTRINSICS_FILE) if f.is_file()),
                      None)
        recorded = {}
        if o is not None:
            intr, how = native_intrinsics(o.fx, o.fy, o.cx, o.cy, first, "ingest.camera_override")
        elif k_file is not None:
            intr, K = camera_intrinsics_file(k_file, first)
            rel = INTRINSICS_FILE if k_file.parent == self.path else f"../{INTRINSICS_FILE}"
            how = f"{rel} (the images' own): {intr.to_dict()}"
            recorded = {"camera_intrinsics_file": {"path": rel, "K": K.tolist()}}
        else:
            intr, how = native_intrinsics(*SEVEN_SCENES_INTRINSICS, first, "7-Scenes Kinect defaults")
        info = SourceInfo(
            intrinsics=intr, has_instance=False, pose_chain=[PoseLink("world", "camera")],
            where={RGB: f"frame-*.color.{ext}", DEPTH: "frame-*.depth.png", "world->camera": "frame-*.pose.txt"},
            provenance={
                "frames": len(ids), **recorded,
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
        stamps = frame_stamps_ns(np.array(ids), self.params.folder_fps)
        return Opened(info, SevenScenesFrames(names=names, stamps=stamps, ext=ext))

    def samples(self, opened: Opened[SevenScenesFrames]) -> Iterator[Sample]:
        seq = opened.state
        for k, (name, stamp) in enumerate(zip(seq.names, seq.stamps.tolist())):
            base = self.path / name
            yield Sample(POSE, stamp, k, self._pose(base.with_name(name + ".pose.txt"), k), key="world->camera",
                         rigid=True)
            colour, depth = base.with_name(f"{name}.color.{seq.ext}"), base.with_name(name + ".depth.png")
            yield Sample(RGB, stamp, k, lambda f=colour, k=k: read_image(f, flags=cv2.IMREAD_COLOR, frame=k,
                                                                          what="colour"), origin=colour)
            yield Sample(DEPTH, stamp, k, lambda f=depth, k=k: self._depth(f, k), origin=depth)

    def _pose(self, file: Path, k: int) -> np.ndarray:
        return read_pose_matrix(file, k, self.params.pose_orthonormal_tol)

    @staticmethod
    def _depth(file: Path, k: int) -> np.ndarray:
        img = read_depth16(file, k, "uint16 millimetres")
        return np.where(img == INVALID_DEPTH, 0, img).astype(np.uint16)
