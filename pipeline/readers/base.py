"""The reader family: one interface for every raw format, a registry, and format detection.

A :class:`Reader` turns a raw log or dataset folder into

- an :class:`Opened` from :meth:`Reader.open`: the :class:`SourceInfo` (intrinsics, the pose chain, provenance,
  ground truth) and the reader's own state of that source (its file lists, poses, topics...);
- a time-ordered stream of :class:`Sample` from :meth:`Reader.samples`, given that :class:`Opened`: colour, depth
  and instance images (decoded lazily) and pose-link samples, each with its own stamp and message index.

A reader keeps nothing of a source on itself: what :meth:`Reader.samples` needs, :meth:`Reader.open` returns.

The shared :mod:`pipeline.readers.matcher` consumes that stream whatever the format, so every
reader gets the same timestamp matching, tolerance, interpolation and unmatched-frame report.
A format is a :class:`Reader` subclass with a ``name`` and a ``layout``, declared by name: zipon's own in
:data:`pipeline.plugins.BUILT_IN_READERS`, a third party's in the ``zipon.readers`` entry points of its package. The
accepted ``scenes.<s>.format`` names, ``zipon ingest --format`` and the messages below all come from that registry.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any, ClassVar, Generic, Iterator, TypeVar

import numpy as np

from pipeline import plugins
from pipeline.config import IngestParams
from pipeline.errors import InputDataError, MissingInputError
from pipeline.geometry import Intrinsics, nearest_rigid, pose_from_tq
from pipeline.imagecodec import read_image_file

# Stream names of samples.
RGB, DEPTH, INSTANCE, POSE = "rgb", "depth", "instance", "pose"
IMAGE_STREAMS = (RGB, DEPTH, INSTANCE)
# A quaternion whose norm is further than this from 1 is malformed (not silently normalised).
QUAT_NORM_TOL = 1e-3


@dataclass
class Sample:
    """One message of one stream.

    ``payload``: for images an array or a zero-argument callable returning it (decoded only when the
    frame is matched): colour ``(H,W,3)`` uint8 RGB, depth ``(H,W)`` uint16 mm or float32 metres
    (NaN/inf/0 = invalid), instance ``(H,W)`` uint16; for poses a ``(4,4)`` float64 transform of
    pose link ``key`` (parent -> child, see :class:`PoseLink`).
    ``index`` is the 0-based message index within its stream (the "frame" errors name). ``origin``: the file
    an image comes from (folder formats), named by errors about its pixels; messages of a log leave it None
    (the topic and index name them).
    """

    stream: str
    stamp_ns: int
    index: int
    payload: Any
    key: str = ""
    rigid: bool = False  # a pose known rigid by construction (from a checked quaternion): skip the matrix check
    origin: Path | None = None

    def array(self) -> np.ndarray:
        if callable(self.payload):
            self.payload = self.payload()
        return self.payload


@dataclass(frozen=True)
class PoseLink:
    """One link of the chain world -> camera. ``static`` holds the transform of a fixed link;
    dynamic links get :class:`Sample` s of stream ``pose`` with ``key == name``."""

    parent: str
    child: str
    static: np.ndarray | None = None

    @property
    def name(self) -> str:
        return f"{self.parent}->{self.child}"


@dataclass
class SourceInfo:
    """What a reader knows before streaming.

    ``pose_chain`` composes left to right into ``T_world_camera`` (OpenCV optical camera, z-up world).
    ``where`` maps each stream (and pose link) to the topic or file it comes from, for messages.
    """

    intrinsics: Intrinsics
    has_instance: bool
    pose_chain: list[PoseLink]
    where: dict[str, str]
    provenance: dict = field(default_factory=dict)
    ground_truth: dict | None = None


#: a reader's own state of one opened source (a frozen dataclass of the reader's module)
State = TypeVar("State")


@dataclass(frozen=True)
class Opened(Generic[State]):
    """What :meth:`Reader.open` found in one source: ``info`` for the ingest, and ``state`` for the reader's own
    :meth:`Reader.samples` (what it listed, parsed or decided while opening)."""

    info: SourceInfo
    state: State


class Reader(ABC):
    """A raw format, found by its ``name`` in the reader registry (:func:`reader_class`) and built by
    :func:`open_reader`. ``layout`` says what :meth:`detect` looks for, in the words of "cannot tell the format".
    After construction a reader holds only its ``path`` and ``params``: what it learns of the source travels in the
    :class:`Opened` that :meth:`open` returns and :meth:`samples` takes."""

    name: ClassVar[str]
    layout: ClassVar[str]
    # The up axis of the dataset's world as documented by the dataset (ingest.world_up 'dataset'), and whether
    # that axis is up only approximately (levelled on the floor when one is found, pipeline.readers.world_up).
    world_up: ClassVar[str] = "+z"
    world_up_levelled: ClassVar[bool] = False

    def __init__(self, path: Path, params: IngestParams):
        self.path = Path(path)
        self.params = params

    @classmethod
    @abstractmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` looks like this format (cheap: names and magic bytes only)."""

    @abstractmethod
    def open(self) -> Opened:
        """Validate the source's layout and return what is known before streaming, with the reader's state of it."""

    @abstractmethod
    def samples(self, opened: Opened) -> Iterator[Sample]:
        """Every message of the source ``opened`` (what :meth:`open` returned), ordered by time; within a stream (pose
        link) stamps must strictly increase."""


#: the readers loaded so far, by format name (filled by :func:`reader_class`)
READERS: dict[str, type[Reader]] = {}


def reader_class(name: str) -> type[Reader] | None:
    """The reader of format ``name``, built in or registered by an installed package; None for a name neither
    declares. Raises ConfigError naming the entry point when a registration does not load or does not fit."""
    return plugins.load_class(plugins.READERS_GROUP, name, Reader, "pipeline.readers.base.Reader", "reader",
                              loaded=READERS)


def all_readers() -> dict[str, type[Reader]]:
    """Every reader of the registry by format name (built-ins first)."""
    return {name: reader_class(name) for name in plugins.reader_names()}


def detect_format(path: Path) -> str:
    """Name of the reader whose :meth:`Reader.detect` accepts ``path``; errors list what was tried."""
    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"{path}: raw data not found")
    readers = all_readers()
    found = [name for name, cls in readers.items() if plugins.detects(cls, path)]  # a failing plug-in: skipped
    if len(found) == 1:
        return found[0]
    if not found:
        layouts = ", ".join(f"{getattr(cls, 'layout', f'a {name} source')} ({name})" for name, cls in readers.items())
        raise InputDataError("cannot tell the format of this path", path=path,
                             expected=f"{layouts}; or set the scene's format (--format)")
    raise InputDataError(f"path matches several formats {found}", path=path, expected="set the scene's format")


def open_reader(path: Path, params: IngestParams, fmt: str = "auto") -> Reader:
    """The reader for ``path`` (``fmt`` a registry name or 'auto')."""
    name = detect_format(path) if fmt == "auto" else fmt
    cls = reader_class(name)
    if cls is None:
        raise InputDataError(f"unknown format {name!r}", path=path,
                             expected=f"one of {plugins.reader_names()} or 'auto'")
    with plugins.running(cls, "open"):
        return cls(Path(path), params)


# ----------------------------------------------------------------------------- helpers for readers

def read_text_lines(path: Path, expected: str) -> list[str]:
    """The lines of a text file (UTF-8; ASCII in every format zipon reads); a byte that is not UTF-8 raises
    :class:`InputDataError` naming the file and the line."""
    data = Path(path).read_bytes()
    try:
        return data.decode("utf-8").splitlines()
    except UnicodeDecodeError as err:
        line = data[:err.start].count(b"\n") + 1
        raise InputDataError(f"byte 0x{data[err.start]:02x} at offset {err.start} is not text ({err.reason})",
                             path=path, field=f"line {line}", expected=expected) from None


def parse_stamp_ns(text: str, *, path=None, line: int | None = None) -> int:
    """Seconds as decimal text ('1305031229.528748') -> int nanoseconds, without float rounding."""
    try:
        return int((Decimal(text) * 1_000_000_000).to_integral_value())
    except InvalidOperation:
        raise InputDataError(f"timestamp {text!r} is not a number", path=path, field=f"line {line}" if line else None,
                             expected="seconds, e.g. 1305031229.528748") from None


def pose_from_tq_checked(values, *, path=None, topic=None, frame: int | None = None, field=None) -> np.ndarray:
    """``(4,4)`` from ``tx ty tz qx qy qz qw``; NaN or a non-unit quaternion raise :class:`InputDataError`."""
    v = np.asarray(values, dtype=np.float64)
    where = {"path": path, "topic": topic, "frame": frame, "field": field}
    if v.shape != (7,) or not np.isfinite(v).all():
        raise InputDataError(f"pose {v.tolist()} is not 7 finite numbers", **where,
                             expected="tx ty tz qx qy qz qw, finite")
    norm = float(np.linalg.norm(v[3:]))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise InputDataError(f"pose quaternion has norm {norm:.6f}: not a rotation", **where,
                             expected=f"a unit quaternion (norm within {QUAT_NORM_TOL} of 1)")
    return pose_from_tq(v[:3], v[3:] / norm)


def frame_stamps_ns(indices: np.ndarray, fps: float) -> np.ndarray:
    """Synthesised stamps for datasets without time: frame index / ``fps``, int64 ns."""
    return np.round(np.asarray(indices, dtype=np.float64) * (1e9 / fps)).astype(np.int64)


def native_intrinsics(fx: float, fy: float, cx: float, cy: float, first_image: Path, what: str
                      ) -> tuple[Intrinsics, str]:
    """Published 640x480 intrinsics, rescaled when the dataset's images (``first_image``) are resampled."""
    import cv2

    base = Intrinsics(fx, fy, cx, cy, 640, 480)
    img = read_image(first_image, flags=cv2.IMREAD_COLOR, frame=0, what="colour")
    h, w = img.shape[:2]
    if (w, h) == (640, 480):
        return base, f"{what}: {base.to_dict()}"
    scaled = base.scaled(w, h)
    return scaled, f"{what} for 640x480, rescaled to the images' {w}x{h}: {scaled.to_dict()}"


def read_depth16(path: Path, frame: int, expected: str) -> np.ndarray:
    """A single-channel 16-bit depth PNG as stored (no unit conversion), decoded strictly; anything else raises
    :class:`InputDataError` naming the file and frame."""
    import cv2

    img = read_image_file(path, cv2.IMREAD_UNCHANGED, frame=frame, what="depth")
    if img.dtype != np.uint16 or img.ndim != 2:
        raise InputDataError("depth image is not a single-channel 16-bit PNG", path=path, frame=frame,
                             expected=expected)
    return img


def read_image(path: Path, *, flags: int, frame: int, what: str) -> np.ndarray:
    """Load an image file (strictly: :mod:`pipeline.imagecodec`); unreadable, truncated or corrupt files raise
    :class:`InputDataError` naming the file and frame. Colour comes back RGB."""
    img = read_image_file(path, flags, frame=frame, what=what)
    if img.ndim == 3:
        img = np.ascontiguousarray(img[..., [2, 1, 0]])
    return img


def read_pose_matrix(file: Path, frame: int, tol: float) -> np.ndarray:
    """A 4x4 camera-to-world matrix from a text file, re-orthonormalised within ``tol``
    (:func:`pipeline.geometry.nearest_rigid`); errors name the file and frame."""
    try:
        T = np.loadtxt(file, dtype=np.float64)
    except ValueError as err:
        raise InputDataError(f"pose is not numeric ({err})", path=file, frame=frame, expected="a 4x4 matrix") from None
    if T.shape != (4, 4):
        raise InputDataError(f"pose has shape {T.shape}", path=file, frame=frame, expected="a 4x4 matrix")
    return nearest_rigid(T, tol=tol, path=file, frame=frame)
