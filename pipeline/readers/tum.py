"""TUM RGB-D benchmark folders (Sturm et al., IROS 2012).

Layout: ``rgb.txt`` / ``depth.txt`` (``timestamp filename``), ``groundtruth.txt`` (``timestamp tx ty tz
qx qy qz qw``: the optical camera in the motion-capture world, camera-to-world), ``rgb/*.png``
640x480 RGB, ``depth/*.png`` uint16 with 5000 units per metre (0 = invalid). Lines starting with
``#`` are comments. Intrinsics: the published fr1/fr2/fr3 values (distortion ignored), chosen by
``ingest.tum_camera`` ('auto': from the folder name, default fr1) or ``ingest.camera_override``.
"""

from __future__ import annotations

import heapq
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics
from pipeline.readers.base import (DEPTH, POSE, RGB, Opened, PoseLink, Reader, Sample, SourceInfo, parse_stamp_ns,
                                   native_intrinsics, pose_from_tq_checked, read_depth16, read_image,
                                   read_text_lines)

# (fx, fy, cx, cy) published for each Kinect of the benchmark, 640x480.
TUM_INTRINSICS = {"fr1": (517.3, 516.5, 318.6, 255.3), "fr2": (520.9, 521.0, 325.1, 249.7),
                  "fr3": (535.4, 539.2, 320.1, 247.6)}


def _table(path: Path, columns: int) -> list[tuple[int, int, list[str]]]:
    """Non-comment lines -> ``(line_no, stamp_ns, rest)``; checks column counts."""
    if not path.is_file():
        raise InputDataError("index file is missing", path=path, expected="the TUM RGB-D layout")
    rows = []
    for no, line in enumerate(read_text_lines(path, f"{columns} text columns a line"), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != columns:
            raise InputDataError(f"line has {len(parts)} columns", path=path, field=f"line {no}",
                                 expected=f"{columns} columns")
        rows.append((no, parse_stamp_ns(parts[0], path=path, line=no), parts[1:]))
    return rows


def tum_depth_to_mm(raw: np.ndarray) -> np.ndarray:
    """uint16 at 5000 per metre -> uint16 millimetres (round half up; 0 stays 0)."""
    return ((raw.astype(np.uint32) + 2) // 5).astype(np.uint16)


#: an index file's rows: ``(line_no, stamp_ns, the other columns)``
Rows = list[tuple[int, int, list[str]]]


@dataclass(frozen=True)
class TumIndex:
    """The opened folder: the rows of ``rgb.txt``, ``depth.txt`` and ``groundtruth.txt``."""

    rgb: Rows
    depth: Rows
    poses: Rows


class TumReader(Reader):
    """See the module doc."""

    name = "tum"
    layout = "a TUM RGB-D folder (rgb.txt, depth.txt)"

    @classmethod
    def detect(cls, path: Path) -> bool:
        return path.is_dir() and (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()

    def _intrinsics(self, first: Path) -> tuple[Intrinsics, str]:
        o = self.params.camera_override
        if o is not None:
            return native_intrinsics(o.fx, o.fy, o.cx, o.cy, first, "ingest.camera_override")
        cam = self.params.tum_camera
        if cam == "auto":
            m = re.search(r"(?:freiburg|fr)([123])", self.path.resolve().name.lower())
            cam = f"fr{m.group(1)}" if m else "fr1"
        return native_intrinsics(*TUM_INTRINSICS[cam], first, f"TUM {cam} (published, distortion ignored)")

    def open(self) -> Opened[TumIndex]:
        rows = {}
        for stream, name in ((RGB, "rgb.txt"), (DEPTH, "depth.txt")):
            rows[stream] = _table(self.path / name, 2)
            for k, (no, _, rest) in enumerate(rows[stream]):
                if not (self.path / rest[0]).is_file():
                    raise InputDataError(f"{name} line {no} lists a missing file", path=self.path / rest[0],
                                         field=f"{name} line {no}", frame=k, expected="the image file to exist")
        rows[POSE] = _table(self.path / "groundtruth.txt", 8)
        for stream, name, expected in ((RGB, "rgb.txt", "timestamp filename lines"),
                                       (DEPTH, "depth.txt", "timestamp filename lines"),
                                       (POSE, "groundtruth.txt", "timestamp tx ty tz qx qy qz qw lines")):
            if not rows[stream]:
                raise InputDataError(f"no {'poses' if stream == POSE else 'frames'} listed: every line is blank or a "
                                     "comment", path=self.path / name, expected=expected)
        intr, how = self._intrinsics(self.path / rows[RGB][0][2][0])
        info = SourceInfo(
            intrinsics=intr, has_instance=False, pose_chain=[PoseLink("world", "camera")],
            where={RGB: "rgb.txt", DEPTH: "depth.txt", "world->camera": "groundtruth.txt"},
            provenance={
                "files": {"rgb": "rgb.txt", "depth": "depth.txt", "pose": "groundtruth.txt"},
                "conversions": [
                    f"intrinsics: {how}",
                    "depth: png / 5000 m -> uint16 mm, rounded ((v + 2) // 5)",
                    "pose: groundtruth tx ty tz qx qy qz qw is camera(optical)-to-world already; world = mocap frame",
                    "stamps: decimal seconds -> int ns (exact)",
                ],
            },
        )
        return Opened(info, TumIndex(rgb=rows[RGB], depth=rows[DEPTH], poses=rows[POSE]))

    def samples(self, opened: Opened[TumIndex]) -> Iterator[Sample]:
        index = opened.state

        def images(stream: str, rows: Rows):
            for k, (no, stamp, rest) in enumerate(rows):
                file = self.path / rest[0]
                if stream == RGB:
                    load = (lambda f=file, k=k: read_image(f, flags=cv2.IMREAD_COLOR, frame=k, what="colour"))
                else:
                    load = (lambda f=file, k=k: tum_depth_to_mm(self._depth(f, k)))
                yield Sample(stream, stamp, k, load, origin=file)

        def poses():
            for k, (no, stamp, rest) in enumerate(index.poses):
                try:
                    values = [float(x) for x in rest]
                except ValueError as err:
                    raise InputDataError(f"pose is not numeric ({err})", path=self.path / "groundtruth.txt",
                                         field=f"line {no}", frame=k, expected="tx ty tz qx qy qz qw") from None
                T = pose_from_tq_checked(values, path=self.path / "groundtruth.txt", field=f"line {no}", frame=k)
                yield Sample(POSE, stamp, k, T, key="world->camera", rigid=True)

        yield from heapq.merge(images(RGB, index.rgb), images(DEPTH, index.depth), poses(), key=lambda s: s.stamp_ns)

    @staticmethod
    def _depth(file: Path, k: int) -> np.ndarray:
        img = read_depth16(file, k, "uint16 depth at 5000 per metre")
        return img
