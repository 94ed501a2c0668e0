"""Replica sequences as NICE-SLAM / ConceptGraphs use them (``Replica/room0``).

Layout: ``results/frameNNNNNN.jpg`` (RGB), ``results/depthNNNNNN.png`` (uint16, ``scale`` units per
metre, 6553.5), ``traj.txt`` (one camera-to-world 4x4 per line, 16 numbers row-major, OpenCV optical
camera), and the camera in ``cam_params.json`` (``{"camera": {w, h, fx, fy, cx, cy, scale}}``, in the
folder or the one above it, as the Replica download ships it) or else NICE-SLAM's ``replica.yaml``
values (1200x680, f 600, c (599.5, 339.5), scale 6553.5); ``ingest.camera_override`` replaces K.
Stamps are synthesised as ``N / ingest.folder_fps``. Poses are re-orthonormalised within
``ingest.pose_orthonormal_tol``. Replica's world is z-up (``world_up`` +z).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics, nearest_rigid
from pipeline.readers.base import (DEPTH, POSE, RGB, Opened, PoseLink, Reader, Sample, SourceInfo, frame_stamps_ns,
                                   read_depth16, read_image, read_text_lines)
from pipeline.userfiles import load_user_file

# NICE-SLAM configs/Replica/replica.yaml
REPLICA_CAMERA = {"w": 1200, "h": 680, "fx": 600.0, "fy": 600.0, "cx": 599.5, "cy": 339.5, "scale": 6553.5}
_FRAME = re.compile(r"^frame(\d+)\.(jpg|png)$")


def _camera(folder: Path) -> tuple[dict, str]:
    for f in (folder / "cam_params.json", folder.parent / "cam_params.json"):
        if f.is_file():
            doc = load_user_file(f, fmt="json")
            try:
                cam = doc["camera"]
                return {k: float(cam[k]) for k in REPLICA_CAMERA}, str(f)
            except (KeyError, TypeError, ValueError) as err:
                raise InputDataError(f"camera parameters unreadable ({err})", path=f, field="camera",
                                     expected='{"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}') from None
    return dict(REPLICA_CAMERA), "NICE-SLAM replica.yaml defaults"


@dataclass(frozen=True)
class ReplicaFrames:
    """The opened sequence: ``(frame number, colour file, depth file)`` per frame with its stamp, the split lines of
    ``traj.txt`` (parsed when streamed) and the depth units per metre."""

    frames: list[tuple[int, Path, Path]]
    stamps: np.ndarray
    rows: list[list[str]]
    scale: float


class ReplicaReader(Reader):
    """See the module doc."""

    name = "replica"
    layout = "a Replica sequence (results/, traj.txt)"

    @classmethod
    def detect(cls, path: Path) -> bool:
        return (path.is_dir() and (path / "traj.txt").is_file() and (path / "results").is_dir()
                and next((path / "results").glob("frame*.jpg"), None) is not None)

    def open(self) -> Opened[ReplicaFrames]:
        res = self.path / "results"
        if not res.is_dir() or not (self.path / "traj.txt").is_file():
            raise InputDataError("no results/ folder or traj.txt", path=self.path,
                                 expected="a Replica sequence: results/frameNNNNNN.jpg, results/depthNNNNNN.png, traj.txt")
        found = sorted((int(m.group(1)), p.name, m.group(1)) for p in res.iterdir() if (m := _FRAME.match(p.name)))
        if not found:
            raise InputDataError("no frameNNNNNN.jpg files", path=res, expected="results/frameNNNNNN.jpg")
        rows = [ln.split() for ln in read_text_lines(self.path / "traj.txt", "16 numbers a line") if ln.strip()]
        if len(rows) < len(found):
            raise InputDataError(f"traj.txt has {len(rows)} poses for {len(found)} frames", path=self.path / "traj.txt",
                                 expected="one 4x4 pose (16 numbers) per frame")
        frames = []
        for k, (i, name, digits) in enumerate(found):
            depth = res / f"depth{digits}.png"
            if not depth.is_file():
                raise InputDataError(f"{name} has no depth file", path=depth, frame=k,
                                     expected="results/depthNNNNNN.png for every frame")
            frames.append((i, res / name, depth))
        cam, origin = _camera(self.path)
        o = self.params.camera_override
        w, h = int(cam["w"]), int(cam["h"])
        intr = Intrinsics(o.fx, o.fy, o.cx, o.cy, w, h) if o else Intrinsics(cam["fx"], cam["fy"], cam["cx"], cam["cy"], w, h)
        info = SourceInfo(
            intrinsics=intr, has_instance=False, pose_chain=[PoseLink("world", "camera")],
            where={RGB: "results/frame*.jpg", DEPTH: "results/depth*.png", "world->camera": "traj.txt"},
            provenance={
                "frames": len(frames),
                "conversions": [
                    f"intrinsics: {'ingest.camera_override' if o else origin}: {intr.to_dict()}",
                    f"depth: png / {cam['scale']} per metre -> uint16 mm (rounded)",
                    f"stamps: synthesised as frame number / ingest.folder_fps ({self.params.folder_fps} Hz)",
                    "pose: traj.txt line N = camera(optical)-to-world 4x4 row-major, re-orthonormalised by SVD "
                    f"(ingest.pose_orthonormal_tol = {self.params.pose_orthonormal_tol}); world = Replica's (z up)",
                ],
            },
        )
        stamps = frame_stamps_ns(np.array([i for i, _, _ in frames]), self.params.folder_fps)
        return Opened(info, ReplicaFrames(frames=frames, stamps=stamps, rows=rows, scale=cam["scale"]))

    def _pose(self, rows: list[list[str]], k: int, i: int) -> np.ndarray:
        where = {"path": self.path / "traj.txt", "frame": k}
        try:
            T = np.array([float(x) for x in rows[i]]).reshape(4, 4)
        except (ValueError, IndexError) as err:
            raise InputDataError(f"line {i + 1} is not 16 numbers ({err})", **where, field=f"line {i + 1}",
                                 expected="a 4x4 camera-to-world matrix, row-major") from None
        return nearest_rigid(T, tol=self.params.pose_orthonormal_tol, **where)

    def samples(self, opened: Opened[ReplicaFrames]) -> Iterator[Sample]:
        seq = opened.state
        for k, ((i, rgb, depth), stamp) in enumerate(zip(seq.frames, seq.stamps.tolist())):
            yield Sample(POSE, stamp, k, self._pose(seq.rows, k, i), key="world->camera", rigid=True)
            yield Sample(RGB, stamp, k, lambda f=rgb, k=k: read_image(f, flags=cv2.IMREAD_COLOR, frame=k, what="colour"),
                         origin=rgb)
            yield Sample(DEPTH, stamp, k, lambda f=depth, k=k: _depth(f, k, seq.scale), origin=depth)


def _depth(file: Path, k: int, scale: float) -> np.ndarray:
    raw = read_depth16(file, k, f"uint16 depth at {scale} per metre")
    return np.clip(np.rint(raw.astype(np.float64) * (1000.0 / scale)), 0, 65535).astype(np.uint16)
