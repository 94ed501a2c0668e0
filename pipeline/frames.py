"""``frames.zarr``: the frame store every downstream stage reads.

Format (version 1)::

    frames.zarr/                 attrs: artifact="frames", format_version, intrinsics {fx,fy,cx,cy,width,height},
    │                                   K, depth_unit="mm", depth_range_m, conventions, provenance, matching,
    │                                   n_frames, ground_truth (simulated scenes: the scene's objects and rooms),
    │                                   world_up (the source's up axis, how it was chosen, the rotation to z-up)
    ├── rgb       (N,H,W,3) uint8    colour, RGB order
    ├── depth     (N,H,W)   uint16   z-depth in millimetres, 0 = invalid
    ├── pose      (N,4,4)   float64  T_world_camera (OpenCV optical camera, z-up world)
    ├── stamp     (N,)      int64    capture time, nanoseconds
    └── instance  (N,H,W)   uint16   optional per-pixel instance ids, 0 = none

Chunks hold ``block_frames`` whole frames, so a reader streams blocks with one chunk read
per array.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from pipeline.errors import ArtifactError
from pipeline.geometry import Intrinsics
from pipeline.scene_gt import GTScene
from pipeline.store import ArrayDigests, ArtifactAttrs, compressor, new_group, open_group

ARTIFACT = "frames"
FORMAT_VERSION = 1
CONVENTIONS = {
    "world": "right-handed, z up, metres",
    "camera": "OpenCV optical: x right, y down, z forward",
    "pose": "T_world_camera, 4x4 float64 (camera -> world)",
    "stamp": "int64 nanoseconds",
    "depth": "uint16 millimetres, 0 = invalid",
}


class FramesAttrs(ArtifactAttrs):
    """The attrs of ``frames.zarr`` (the tree above). ``n_frames`` and ``matching`` are recorded when the writer
    closes; ``ground_truth`` is the simulator's scene (checked as a :class:`GTScene` when read)."""

    intrinsics: Intrinsics  # fx, fy, cx, cy, width, height (Intrinsics.to_dict)
    K: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
    conventions: dict[str, str]
    depth_unit: str = "mm"
    depth_range_m: tuple[float, float] | None = None
    n_frames: int | None = None
    provenance: dict[str, Any] = {}
    matching: dict[str, Any] | None = None
    world_up: dict[str, Any] | None = None
    ground_truth: dict[str, Any] | None = None


@dataclass
class FrameBlock:
    """A block of consecutive frames (all arrays share the leading frame axis B)."""

    rgb: np.ndarray  # (B,H,W,3) uint8
    depth_mm: np.ndarray  # (B,H,W) uint16
    T_world_camera: np.ndarray  # (B,4,4) float64
    stamp_ns: np.ndarray  # (B,) int64
    instance: np.ndarray | None = None  # (B,H,W) uint16
    start: int = 0  # index of the first frame in the store

    def __len__(self) -> int:
        return len(self.stamp_ns)

    def depth_m(self) -> np.ndarray:
        return self.depth_mm.astype(np.float32) * np.float32(1e-3)


class FrameStoreWriter:
    """Appends frame blocks to a new ``frames.zarr`` at ``path`` (a stage's temporary output); with ``digests``
    (:class:`pipeline.store.ArrayDigests`) the arrays' content digests are kept as the blocks are written."""

    def __init__(
        self,
        path: Path,
        intrinsics: Intrinsics,
        *,
        attrs: dict,
        block_frames: int = 16,
        with_instance: bool = False,
        compression_level: int = 3,
        codec: str = "zstd",
        digests: ArrayDigests | None = None,
    ):
        self.path = Path(path)
        self.digests = digests  # kept while writing, so the runner need not read the store back to digest it
        self.intrinsics = intrinsics
        self.block_frames = block_frames
        self.n = 0
        h, w = intrinsics.height, intrinsics.width
        self.group = new_group(self.path, FramesAttrs.checked(
            {**attrs, "intrinsics": intrinsics.to_dict(), "K": intrinsics.K.tolist(), "conventions": CONVENTIONS},
            self.path))
        b = block_frames
        # Blosc-zstd by default; 'lz4' trades size (~1.2x vs ~1.5x on camera colour) for ~10x faster writes.
        if codec not in ("zstd", "lz4"):
            raise ValueError(f"codec {codec!r}: expected 'zstd' or 'lz4'")
        if codec == "zstd":
            c_img = compressor(compression_level, shuffle="noshuffle")
            c_int = compressor(compression_level, shuffle="shuffle")
        else:
            from zarr.codecs import BloscCodec

            c_img = BloscCodec(cname="lz4", clevel=compression_level, shuffle="noshuffle")
            c_int = BloscCodec(cname="lz4", clevel=compression_level, shuffle="shuffle")
        g = self.group
        self.arrays = {
            "rgb": g.create_array("rgb", shape=(0, h, w, 3), chunks=(b, h, w, 3), dtype="uint8", compressors=c_img),
            "depth": g.create_array("depth", shape=(0, h, w), chunks=(b, h, w), dtype="uint16", compressors=c_int),
            "pose": g.create_array("pose", shape=(0, 4, 4), chunks=(max(b, 1024), 4, 4), dtype="float64",
                                   compressors=c_int),
            "stamp": g.create_array("stamp", shape=(0,), chunks=(max(b, 1024),), dtype="int64", compressors=c_int),
        }
        if with_instance:
            self.arrays["instance"] = g.create_array(
                "instance", shape=(0, h, w), chunks=(b, h, w), dtype="uint16", compressors=c_int
            )
        self.arrays["rgb"].attrs.update({"unit": "8-bit RGB"})
        self.arrays["depth"].attrs.update({"unit": "mm", "invalid": 0})
        self.arrays["pose"].attrs.update({"frame": "T_world_camera"})
        self.arrays["stamp"].attrs.update({"unit": "ns"})

    def append(self, block: FrameBlock) -> None:
        """Write ``block`` after the frames already written; shapes and dtypes are checked."""
        b = len(block)
        if b == 0:
            return
        h, w = self.intrinsics.height, self.intrinsics.width
        expect = {
            "rgb": (block.rgb, (b, h, w, 3), np.uint8),
            "depth": (block.depth_mm, (b, h, w), np.uint16),
            "pose": (block.T_world_camera, (b, 4, 4), np.float64),
            "stamp": (block.stamp_ns, (b,), np.int64),
        }
        if "instance" in self.arrays:
            if block.instance is None:
                raise ArtifactError(f"{self.path}: block at frame {self.n} lacks the instance image")
            expect["instance"] = (block.instance, (b, h, w), np.uint16)
        for name, (arr, shape, dtype) in expect.items():
            if arr.shape != shape or arr.dtype != dtype:
                raise ArtifactError(
                    f"{self.path}: {name} block at frame {self.n} has {arr.dtype}{arr.shape}, expected {np.dtype(dtype)}{shape}"
                )
        for name, (arr, _, _) in expect.items():
            z = self.arrays[name]
            z.resize((self.n + b,) + z.shape[1:])
            z[self.n : self.n + b] = arr
            if self.digests is not None:
                self.digests.update(name, arr)
        self.n += b

    def close(self, **final_attrs) -> int:
        """Record ``n_frames`` and any final attrs (e.g. the matching summary); returns the frame count."""
        final = {"n_frames": self.n, **final_attrs}
        FramesAttrs.checked({**self.group.attrs, **final}, self.path)
        self.group.attrs.update(final)
        return self.n


class FrameStore:
    """Read-only view of a ``frames.zarr``: ``meta`` the typed :class:`FramesAttrs` (``attrs`` the same as a plain
    dict), ``intrinsics``, ``n_frames``, :attr:`ground_truth`."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.group = open_group(self.path, artifact=ARTIFACT, format_version=FORMAT_VERSION)
        self.attrs = dict(self.group.attrs)
        self.meta = FramesAttrs.read(self.attrs, self.path)
        self.intrinsics = self.meta.intrinsics
        self.n_frames = int(self.group["stamp"].shape[0])
        self.has_instance = "instance" in self.group
        self._gt: GTScene | None = None

    @property
    def block_frames(self) -> int:
        return int(self.group["rgb"].chunks[0])

    @property
    def ground_truth(self) -> GTScene | None:
        """The scene's ground truth (simulated scenes), checked on first use; None for a real recording."""
        if self._gt is None and self.meta.ground_truth is not None:
            self._gt = GTScene.read(self.meta.ground_truth, f"{self.path}: attrs.ground_truth")
        return self._gt

    def poses(self) -> np.ndarray:
        return self.group["pose"][:]

    def stamps(self) -> np.ndarray:
        return self.group["stamp"][:]

    def read(self, start: int, stop: int, *, rgb: bool = True, depth: bool = True, instance: bool = False) -> FrameBlock:
        g = self.group
        h, w = self.intrinsics.height, self.intrinsics.width
        n = stop - start
        return FrameBlock(
            rgb=g["rgb"][start:stop] if rgb else np.zeros((n, h, w, 3), np.uint8),
            depth_mm=g["depth"][start:stop] if depth else np.zeros((n, h, w), np.uint16),
            T_world_camera=g["pose"][start:stop],
            stamp_ns=g["stamp"][start:stop],
            instance=g["instance"][start:stop] if (instance and self.has_instance) else None,
            start=start,
        )

    def iter_blocks(
        self, block_frames: int | None = None, *, start: int = 0, stop: int | None = None, **what
    ) -> Iterator[FrameBlock]:
        """Stream ``[start, stop)`` in blocks (default: the chunk size, one chunk read per array)."""
        step = block_frames or self.block_frames
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        for s in range(start, stop, step):
            yield self.read(s, min(s + step, stop), **what)
