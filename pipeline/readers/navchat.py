"""navchat (ORION reference code) recordings.

Layout (one scene per folder): ``rgb/{scene}_{i}.png`` (RGB), ``depth/{scene}_{i}.npy`` (uint16 mm),
``semantic/{scene}_{i}.npy`` (instance ids, optional), ``pose/{scene}_{i}.txt`` one line of 7 numbers:
the agent *base* pose in Habitat's world (y up, -z forward). The camera sits
``ingest.navchat_camera_height_m`` above the base; hfov 90 deg (fx = fy = 320, cx = 320, cy = 240 at
640x480) unless ``ingest.camera_override``. Stamps are synthesised as ``i / ingest.folder_fps``.

Quaternion quirk: navchat writes ``quaternion.as_float_array(q)[::-1]``, i.e. numpy-quaternion's
``(w, x, y, z)`` reversed to ``(z, y, x, w)``, and its loader reads that as ``(x, y, z, w)`` -- right
only for yaw-only motion. We undo the reversal: file ``a b c d`` -> ``(qx, qy, qz, qw) = (c, b, a, d)``
(identical to navchat for yaw-only poses, correct for any other).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics, habitat_to_world
from pipeline.readers.base import (DEPTH, INSTANCE, POSE, RGB, Opened, PoseLink, Reader, Sample, SourceInfo, frame_stamps_ns,
                                   pose_from_tq_checked, read_image)

NAVCHAT_HFOV_DEG = 90.0
_RGB = re.compile(r"^(.+)_(\d+)\.png$")


@dataclass(frozen=True)
class NavchatFrames:
    """The opened recording: its scene name, frame numbers and their stamps, and whether it has ``semantic/``."""

    scene: str
    ids: list[int]
    stamps: np.ndarray
    has_instance: bool


class NavchatReader(Reader):
    """See the module doc."""

    name = "navchat"
    layout = "a navchat recording (rgb/, depth/*.npy, pose/)"

    @classmethod
    def detect(cls, path: Path) -> bool:
        return (path.is_dir() and (path / "rgb").is_dir() and (path / "pose").is_dir()
                and next((path / "depth").glob("*.npy"), None) is not None)

    def open(self) -> Opened[NavchatFrames]:
        for sub in ("rgb", "depth", "pose"):
            if not (self.path / sub).is_dir():
                raise InputDataError(f"no {sub}/ folder", path=self.path / sub,
                                     expected="a navchat recording folder with rgb/, depth/, pose/ (and semantic/)")
        found = [(m.group(1), int(m.group(2))) for p in (self.path / "rgb").iterdir() if (m := _RGB.match(p.name))]
        if not found:
            raise InputDataError("no rgb/{scene}_{i}.png files", path=self.path / "rgb",
                                 expected="files rgb/{scene}_{i}.png of exactly one scene")
        scenes = sorted({s for s, _ in found})
        if len(scenes) != 1:
            raise InputDataError(f"rgb/ holds scenes {scenes}", path=self.path / "rgb",
                                 expected="files rgb/{scene}_{i}.png of exactly one scene")
        scene = scenes[0]
        ids = sorted(i for _, i in found)
        has_instance = (self.path / "semantic").is_dir()
        for k, i in enumerate(ids):
            for sub, ext in (("depth", "npy"), ("pose", "txt")) + ((("semantic", "npy"),) if has_instance else ()):
                f = self._file(scene, sub, i, ext)
                if not f.is_file():
                    raise InputDataError(f"rgb/{scene}_{i}.png has no {sub} file", path=f, frame=k,
                                         expected="depth, pose (and semantic) files for every rgb frame")
        first = read_image(self._file(scene, "rgb", ids[0], "png"), flags=cv2.IMREAD_COLOR, frame=0, what="colour")
        h, w = first.shape[:2]
        o = self.params.camera_override
        # hfov 90 deg: f = (w / 2) / tan(45 deg) = w / 2 exactly (from_hfov would leave 320.00000000000006)
        intr = Intrinsics(o.fx, o.fy, o.cx, o.cy, w, h) if o else Intrinsics(w / 2.0, w / 2.0, w / 2.0, h / 2.0, w, h)
        info = SourceInfo(
            intrinsics=intr, has_instance=has_instance, pose_chain=[PoseLink("world", "camera")],
            where={RGB: "rgb/", DEPTH: "depth/", INSTANCE: "semantic/", "world->camera": "pose/"},
            provenance={
                "scene": scene, "frames": len(ids),
                "conversions": [
                    f"intrinsics: {'ingest.camera_override' if o else f'hfov {NAVCHAT_HFOV_DEG} deg'}: "
                    f"{intr.to_dict()}",
                    f"stamps: synthesised as frame number / ingest.folder_fps ({self.params.folder_fps} Hz)",
                    "pose: file 'x y z a b c d' with (a, b, c, d) = reversed (w, x, y, z) -> q_xyzw = (c, b, a, d)",
                    f"pose: Habitat base (y up) -> camera {self.params.navchat_camera_height_m} m above the base, OpenCV optical, z-up world "
                    "(pipeline.geometry.habitat_to_world)",
                    "depth: uint16 mm kept; semantic ids -> uint16 instance",
                ],
            },
        )
        stamps = frame_stamps_ns(np.array(ids), self.params.folder_fps)
        return Opened(info, NavchatFrames(scene=scene, ids=ids, stamps=stamps, has_instance=has_instance))

    def _file(self, scene: str, sub: str, i: int, ext: str) -> Path:
        return self.path / sub / f"{scene}_{i}.{ext}"

    def samples(self, opened: Opened[NavchatFrames]) -> Iterator[Sample]:
        rec = opened.state
        for k, (i, stamp) in enumerate(zip(rec.ids, rec.stamps.tolist())):
            yield Sample(POSE, stamp, k, self._pose(self._file(rec.scene, "pose", i, "txt"), k), key="world->camera",
                         rigid=True)
            rgb, depth, semantic = (self._file(rec.scene, sub, i, ext) for sub, ext in
                                    (("rgb", "png"), ("depth", "npy"), ("semantic", "npy")))
            yield Sample(RGB, stamp, k, lambda f=rgb, k=k: read_image(f, flags=cv2.IMREAD_COLOR, frame=k, what="colour"),
                         origin=rgb)
            yield Sample(DEPTH, stamp, k, lambda f=depth, k=k: self._npy(f, k, "depth"), origin=depth)
            if rec.has_instance:
                yield Sample(INSTANCE, stamp, k, lambda f=semantic, k=k: self._npy(f, k, "semantic"), origin=semantic)

    def _pose(self, file: Path, k: int) -> np.ndarray:
        try:
            v = [float(x) for x in file.read_text().split()]
        except ValueError as err:
            raise InputDataError(f"pose is not numeric ({err})", path=file, frame=k,
                                 expected="x y z a b c d") from None
        if len(v) != 7:
            raise InputDataError(f"pose has {len(v)} numbers", path=file, frame=k, expected="7: x y z a b c d")
        a, b, c, d = v[3:]
        T_hab_base = pose_from_tq_checked(v[:3] + [c, b, a, d], path=file, frame=k)
        return habitat_to_world(T_hab_base, self.params.navchat_camera_height_m)

    @staticmethod
    def _npy(file: Path, k: int, what: str) -> np.ndarray:
        try:
            arr = np.load(file, allow_pickle=False)
        except (OSError, EOFError, ValueError) as err:  # cut short, not a .npy, an object array
            raise InputDataError(f"{what} array could not be read ({err})", path=file, frame=k,
                                 expected="a whole .npy file of (H,W) integers") from None
        if arr.ndim == 3 and arr.shape[-1] == 1:
            arr = arr[..., 0]
        integral = np.issubdtype(arr.dtype, np.integer)
        if arr.ndim != 2 or not integral or arr.min(initial=0) < 0 or arr.max(initial=0) > 65535:
            raise InputDataError(f"{what} array is {arr.dtype}{arr.shape}", path=file, frame=k,
                                 expected=f"(H,W) integers in 0..65535 ({'mm' if what == 'depth' else 'instance ids'})")
        return arr.astype(np.uint16)
