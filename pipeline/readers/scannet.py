"""ScanNet scenes exported by its SensReader (``reader.py --export_color_images --export_depth_images
--export_poses --export_intrinsics``).

Layout: ``color/N.jpg`` (1296x968 RGB), ``depth/N.png`` (640x480 uint16 mm, 0 = invalid), ``pose/N.txt``
(4x4 camera-to-world, OpenCV optical camera; ``-inf`` where tracking failed), ``intrinsic/intrinsic_color.txt``
and ``intrinsic_depth.txt`` (4x4, K in the top-left), optionally ``extrinsic_color.txt`` /
``extrinsic_depth.txt`` (each camera to the sensor rig; identity when absent). ``N`` counts from 0 with
no padding. Stamps are synthesised as ``N / ingest.folder_fps`` (30 Hz in ScanNet).

Frames are stored at the depth resolution: colour is resampled to it (area averaging; its K scaled)
and depth is registered into that colour camera (:mod:`pipeline.readers.registration`). Frames whose
pose is not finite are dropped and counted (attrs ``provenance.frames_dropped_invalid_pose``); the
rest are re-orthonormalised within ``ingest.pose_orthonormal_tol``. ScanNet's world is z-up.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics, invert_pose, nearest_rigid
from pipeline.readers.base import (DEPTH, POSE, RGB, Opened, PoseLink, Reader, Sample, SourceInfo, frame_stamps_ns,
                                   read_depth16, read_image)
from pipeline.readers.matcher import index_ranges
from pipeline.readers.registration import DepthRegistration

_NUM = re.compile(r"^(\d+)\.(jpg|png)$")


def _matrix(file: Path, what: str) -> np.ndarray:
    try:
        M = np.loadtxt(file, dtype=np.float64)
    except (OSError, ValueError) as err:
        raise InputDataError(f"{what} unreadable ({err})", path=file, expected="a 4x4 matrix") from None
    if M.shape != (4, 4):
        raise InputDataError(f"{what} has shape {M.shape}", path=file, expected="a 4x4 matrix")
    return M


@dataclass(frozen=True)
class ScanNetFrames:
    """The opened scene: the frame numbers kept (finite pose) with their poses and stamps, the colour files'
    extension, the stored camera (colour K at the depth size) and the depth registration into it (None: aligned)."""

    ids: list[int]
    poses: dict[int, np.ndarray]
    stamps: np.ndarray
    color_ext: str
    out: Intrinsics
    registration: DepthRegistration | None


class ScanNetReader(Reader):
    """See the module doc."""

    name = "scannet"
    layout = "an exported ScanNet scene (color/, depth/, pose/, intrinsic/)"

    @classmethod
    def detect(cls, path: Path) -> bool:
        return (path.is_dir() and all((path / d).is_dir() for d in ("color", "depth", "pose"))
                and (path / "intrinsic" / "intrinsic_color.txt").is_file())

    def open(self) -> Opened[ScanNetFrames]:
        for sub in ("color", "depth", "pose", "intrinsic"):
            if not (self.path / sub).is_dir():
                raise InputDataError(f"no {sub}/ folder", path=self.path / sub,
                                     expected="an exported ScanNet scene: color/, depth/, pose/, intrinsic/")
        ids = sorted(int(m.group(1)) for p in (self.path / "color").iterdir() if (m := _NUM.match(p.name)))
        if not ids:
            raise InputDataError("no color/N.jpg files", path=self.path / "color", expected="color/0.jpg, color/1.jpg, ...")
        color_ext = "jpg" if (self.path / f"color/{ids[0]}.jpg").is_file() else "png"
        poses, dropped = {}, []
        for k, i in enumerate(ids):
            for sub, name in (("depth", f"{i}.png"), ("pose", f"{i}.txt")):
                if not (self.path / sub / name).is_file():
                    raise InputDataError(f"color/{i}.{color_ext} has no {sub} file", path=self.path / sub / name,
                                         frame=k, expected="depth and pose files for every colour frame")
            T = _matrix(self.path / f"pose/{i}.txt", "pose")
            if not np.isfinite(T).all():
                dropped.append(i)  # ScanNet writes -inf where its tracking failed
                continue
            poses[i] = nearest_rigid(T, tol=self.params.pose_orthonormal_tol, path=self.path / f"pose/{i}.txt", frame=k)
        kept = [i for i in ids if i in poses]
        if not kept:
            raise InputDataError(f"all {len(ids)} poses are invalid (-inf)", path=self.path / "pose",
                                 expected="finite camera-to-world matrices")
        depth0 = read_depth16(self.path / f"depth/{kept[0]}.png", 0, "uint16 millimetres")
        color0 = read_image(self.path / f"color/{kept[0]}.{color_ext}", flags=cv2.IMREAD_COLOR, frame=0,
                            what="colour")
        (hd, wd), (hc, wc) = depth0.shape, color0.shape[:2]
        intr_dir = self.path / "intrinsic"
        K_c = _matrix(intr_dir / "intrinsic_color.txt", "colour intrinsics")[:3, :3]
        depth_file = intr_dir / "intrinsic_depth.txt"
        K_d = _matrix(depth_file, "depth intrinsics")[:3, :3] if depth_file.is_file() else None
        o = self.params.camera_override
        color = Intrinsics(o.fx, o.fy, o.cx, o.cy, wc, hc) if o else Intrinsics.from_K(K_c, wc, hc)
        out = color.scaled(wd, hd)
        depth = Intrinsics.from_K(K_d, wd, hd) if K_d is not None else out
        E = {n: _matrix(intr_dir / f"extrinsic_{n}.txt", f"{n} extrinsics") if (intr_dir / f"extrinsic_{n}.txt").is_file()
             else np.eye(4) for n in ("color", "depth")}
        T_color_depth = invert_pose(E["color"]) @ E["depth"]
        same = depth == out and np.allclose(T_color_depth, np.eye(4), rtol=0, atol=1e-12)
        registration = None if same else DepthRegistration(depth, out, T_color_depth)
        info = SourceInfo(
            intrinsics=out, has_instance=False, pose_chain=[PoseLink("world", "camera")],
            where={RGB: f"color/*.{color_ext}", DEPTH: "depth/*.png", "world->camera": "pose/*.txt"},
            provenance={
                "frames": len(ids),
                "frames_dropped_invalid_pose": {"count": len(dropped), "ranges": index_ranges(dropped)},
                "conversions": [
                    f"colour: {wc}x{hc} resampled to the depth's {wd}x{hd} (area); K "
                    f"{'ingest.camera_override' if o else 'intrinsic_color.txt'} scaled: {out.to_dict()}",
                    "depth: " + (f"{registration.describe()} (intrinsic_depth.txt, extrinsic_*.txt)"
                                 if registration else "on the colour camera (same K at the depth size, identity "
                                 "extrinsics): stored as recorded"),
                    f"stamps: synthesised as frame number / ingest.folder_fps ({self.params.folder_fps} Hz)",
                    f"pose: pose/N.txt camera(optical)-to-world, re-orthonormalised by SVD (ingest.pose_orthonormal_tol"
                    f" = {self.params.pose_orthonormal_tol}); {len(dropped)} frames with -inf poses dropped; "
                    "world = the scan's (z up)",
                ],
            },
        )
        stamps = frame_stamps_ns(np.array(kept), self.params.folder_fps)
        return Opened(info, ScanNetFrames(ids=kept, poses=poses, stamps=stamps, color_ext=color_ext, out=out,
                                          registration=registration))

    def samples(self, opened: Opened[ScanNetFrames]) -> Iterator[Sample]:
        scan = opened.state
        for k, (i, stamp) in enumerate(zip(scan.ids, scan.stamps.tolist())):
            yield Sample(POSE, stamp, k, scan.poses[i], key="world->camera", rigid=True)
            yield Sample(RGB, stamp, k, lambda i=i, k=k: self._colour(scan, i, k),
                         origin=self.path / f"color/{i}.{scan.color_ext}")
            yield Sample(DEPTH, stamp, k, lambda i=i, k=k: self._depth(scan, i, k), origin=self.path / f"depth/{i}.png")

    def _depth(self, scan: ScanNetFrames, i: int, k: int) -> np.ndarray:
        depth = read_depth16(self.path / f"depth/{i}.png", k, "uint16 millimetres")
        return scan.registration(depth) if scan.registration else depth

    def _colour(self, scan: ScanNetFrames, i: int, k: int) -> np.ndarray:
        img = read_image(self.path / f"color/{i}.{scan.color_ext}", flags=cv2.IMREAD_COLOR, frame=k, what="colour")
        if img.shape[:2] == (scan.out.height, scan.out.width):
            return img
        return cv2.resize(img, (scan.out.width, scan.out.height), interpolation=cv2.INTER_AREA)
