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


_K_EXPECTED = ("a pinhole camera in the top-left 3x3 of a 4x4 matrix: fx and fy > 0, the principal point inside "
               "the image, no skew, last row 0 0 1")
_E_EXPECTED = ("a rigid transform (a rotation and a translation, last row 0 0 0 1) from the camera to the sensor "
               "rig, orthonormal within ingest.pose_orthonormal_tol")


def _intrinsics(file: Path, what: str, width: int, height: int) -> np.ndarray:
    """The 3x3 ``K`` of a ScanNet ``intrinsic_*.txt``, checked to be a pinhole camera of a ``width`` x ``height``
    image (:class:`InputDataError` naming the file otherwise)."""
    K = _matrix(file, what)[:3, :3]
    if not np.isfinite(K).all():
        raise InputDataError(f"{what} hold NaN or inf", path=file, expected=_K_EXPECTED)
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    if fx <= 0 or fy <= 0:
        raise InputDataError(f"{what}: focal lengths fx {fx:g}, fy {fy:g} (a camera with a focal length of 0 or "
                             "less projects nothing)", path=file, expected=_K_EXPECTED)
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
        raise InputDataError(f"{what}: not a pinhole camera matrix: {K.tolist()}", path=file, expected=_K_EXPECTED)
    if not (0 < cx < width and 0 < cy < height):
        raise InputDataError(f"{what}: principal point ({cx:g}, {cy:g}) is outside the {width}x{height} images",
                             path=file, expected=_K_EXPECTED)
    return K


def _extrinsics(file: Path, what: str, tol: float) -> np.ndarray:
    """A ScanNet ``extrinsic_*.txt``, checked to be rigid: a matrix that scales or shears would stretch every depth
    pixel silently, so it is refused naming the file (re-orthonormalised by SVD within ``tol``)."""
    from pipeline.geometry import rigid_error

    E = _matrix(file, what)
    err = float(rigid_error(E))
    if not err <= tol:
        if not np.isfinite(err):
            why = "hold NaN or inf"
        else:
            scales = np.linalg.svd(E[:3, :3], compute_uv=False)
            why = (f"are not a rigid transform: the 3x3 part scales by {scales.min():.4g} to {scales.max():.4g}"
                   if np.abs(scales - 1).max() > tol else f"are not a rigid transform (error {err:.2e})")
        raise InputDataError(f"{what} {why}", path=file, expected=_E_EXPECTED)
    return nearest_rigid(E, tol=tol, path=file)


def _frame_numbers(folder: Path) -> dict[int, str]:
    """``{N: file name}`` of ``folder``'s ``N.jpg`` / ``N.png`` files. ScanNet's exporter writes ``N`` without
    padding; an export whose names mix padded (``000012.jpg``) and plain (``12.jpg``) numbers, or that holds one
    number twice, is refused naming two of the files."""
    found: dict[int, str] = {}
    padded = plain = None
    for p in sorted(folder.iterdir()):
        m = _NUM.match(p.name)
        if not m:
            continue
        number = int(m.group(1))
        if number in found:
            raise InputDataError(f"{found[number]} and {p.name} are both frame {number}", path=folder,
                                 expected="one colour file per frame number")
        found[number] = p.name
        if len(m.group(1)) > 1 and m.group(1).startswith("0"):
            padded = padded or p.name
        else:
            plain = plain or p.name
    if padded and plain:
        raise InputDataError(f"frame names mix zero-padded ({folder / padded}) and plain ({folder / plain}) numbers",
                             path=folder, expected="one naming throughout: ScanNet's exporter writes 0.jpg, 1.jpg, ... "
                                                   "(no padding)")
    return found


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
        names = _frame_numbers(self.path / "color")
        ids = sorted(names)
        if names and names[ids[0]] != f"{ids[0]}.{names[ids[0]].rsplit('.', 1)[1]}":
            raise InputDataError(f"frame names are zero-padded ({self.path / 'color' / names[ids[0]]}); depth/ and "
                                 f"pose/ are read as {ids[0]}.png and {ids[0]}.txt", path=self.path / "color",
                                 expected="ScanNet's exporter naming: 0.jpg, 1.jpg, ... (no padding)")
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
        K_c = _intrinsics(intr_dir / "intrinsic_color.txt", "colour intrinsics", wc, hc)
        depth_file = intr_dir / "intrinsic_depth.txt"
        K_d = _intrinsics(depth_file, "depth intrinsics", wd, hd) if depth_file.is_file() else None
        o = self.params.camera_override
        color = Intrinsics(o.fx, o.fy, o.cx, o.cy, wc, hc) if o else Intrinsics.from_K(K_c, wc, hc)
        out = color.scaled(wd, hd)
        depth = Intrinsics.from_K(K_d, wd, hd) if K_d is not None else out
        tol = self.params.pose_orthonormal_tol
        E = {n: _extrinsics(intr_dir / f"extrinsic_{n}.txt", f"{n} extrinsics", tol)
             if (intr_dir / f"extrinsic_{n}.txt").is_file() else np.eye(4) for n in ("color", "depth")}
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
