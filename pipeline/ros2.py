"""ROS 2 messages without ROS: definitions, a log writer, and fast CDR image decoding.

The definitions below are the ROS 2 interface files (``ros2 interface show``) with comments and
constants stripped, in the form ``mcap_ros2`` parses: the main type first, dependent types after
``====`` lines headed ``MSG: pkg/Type``.

:class:`Ros2LogWriter` records a camera the way a robot does (topic names of the RealSense ROS 2
driver, an ``image_transport`` compressed variant, ``/tf`` + ``/tf_static``)::

    /camera/color/image_raw                 sensor_msgs/Image rgb8            (raw transport)
    /camera/depth/image_raw                 sensor_msgs/Image 16UC1 mm, aligned to colour
    /camera/instance/image_raw              sensor_msgs/Image 16UC1 instance ids (0 = none)
    /camera/color/image_raw/compressed      sensor_msgs/CompressedImage "rgb8; png compressed bgr8"
    /camera/depth/image_raw/compressedDepth sensor_msgs/CompressedImage "16UC1; compressedDepth png"
                                            (12-byte compressed_depth_image_transport ConfigHeader + PNG)
    /camera/instance/image_raw/compressed   sensor_msgs/CompressedImage "16UC1; png" (16-bit PNG)
    /camera/color/camera_info               sensor_msgs/CameraInfo (plumb_bob, zero distortion)
    /camera/pose                            geometry_msgs/PoseStamped, frame "map" -> camera optical
    /tf, /tf_static                         map -> odom -> base_link -> camera_link -> camera_color_optical_frame

Every message's log time equals its header stamp. Chunks are zstd-compressed (lz4 on request).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics, invert_pose, pose_from_tq, pose_to_tq
from pipeline.imagecodec import PNG_MAGIC, decode_image

# ----------------------------------------------------------------------------- definitions

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"


def _msgdef(main: str, deps: list[tuple[str, str]]) -> str:
    sep = "=" * 80
    return main + "".join(f"{sep}\nMSG: {name}\n{text}" for name, text in deps)


_HDR_DEPS = [("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME)]
_POINT = "float64 x\nfloat64 y\nfloat64 z\n"
_QUAT = "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"

MSGDEFS: dict[str, str] = {
    "sensor_msgs/msg/Image": _msgdef(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
        "uint32 step\nuint8[] data\n", _HDR_DEPS),
    "sensor_msgs/msg/CompressedImage": _msgdef("std_msgs/Header header\nstring format\nuint8[] data\n", _HDR_DEPS),
    "sensor_msgs/msg/CameraInfo": _msgdef(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
        "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
        "sensor_msgs/RegionOfInterest roi\n",
        _HDR_DEPS + [("sensor_msgs/RegionOfInterest",
                      "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n")]),
    "geometry_msgs/msg/PoseStamped": _msgdef(
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
        _HDR_DEPS + [("geometry_msgs/Pose", "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n"),
                     ("geometry_msgs/Point", _POINT), ("geometry_msgs/Quaternion", _QUAT)]),
    "tf2_msgs/msg/TFMessage": _msgdef(
        "geometry_msgs/TransformStamped[] transforms\n",
        [("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\n"
                                            "geometry_msgs/Transform transform\n"),
         ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME),
         ("geometry_msgs/Transform", "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"),
         ("geometry_msgs/Vector3", _POINT), ("geometry_msgs/Quaternion", _QUAT)]),
}
IMAGE, COMPRESSED, CAMERA_INFO, POSE_STAMPED, TF = (
    "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo",
    "geometry_msgs/msg/PoseStamped", "tf2_msgs/msg/TFMessage")

# Topics and frames written by Ros2LogWriter (readers auto-detect, they do not rely on these).
TOPICS = {
    "rgb": "/camera/color/image_raw",
    "depth": "/camera/depth/image_raw",
    "instance": "/camera/instance/image_raw",
    "camera_info": "/camera/color/camera_info",
    "pose": "/camera/pose",
    "tf": "/tf",
    "tf_static": "/tf_static",
}
COMPRESSED_SUFFIX = {"rgb": "/compressed", "depth": "/compressedDepth", "instance": "/compressed"}
WORLD_FRAME, ODOM_FRAME, BASE_FRAME, CAMERA_LINK, OPTICAL_FRAME = (
    "map", "odom", "base_link", "camera_link", "camera_color_optical_frame")
# Static mount of the camera body on the base (x forward, y left, z up), metres.
CAMERA_MOUNT_XYZ = (0.05, 0.0, 0.88)
# camera_link (x fwd, y left, z up) -> optical (x right, y down, z fwd): REP 103 / REP 105.
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# A fixed map -> odom correction, so the chain exercises every link (not the identity).
T_MAP_ODOM = pose_from_tq(np.array([0.25, -0.10, 0.0]), np.array([0.0, 0.0, np.sin(0.05), np.cos(0.05)]))

# ROS image encodings zipon reads: encoding -> (dtype, channels).
RAW_ENCODINGS: dict[str, tuple[str, int]] = {
    "rgb8": ("u1", 3), "bgr8": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4), "mono8": ("u1", 1),
    "16UC1": ("u2", 1), "mono16": ("u2", 1), "32FC1": ("f4", 1),
}


def _t_link_optical() -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_LINK_OPTICAL
    return T


def _t_base_link() -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = CAMERA_MOUNT_XYZ
    return T


T_BASE_OPTICAL = _t_base_link() @ _t_link_optical()


# ----------------------------------------------------------------------------- writer

def _stamp(stamp_ns: int) -> dict:
    return {"sec": int(stamp_ns // 1_000_000_000), "nanosec": int(stamp_ns % 1_000_000_000)}


def _transform_msg(stamp_ns: int, parent: str, child: str, T: np.ndarray) -> dict:
    t, q = pose_to_tq(T)
    return {"header": {"stamp": _stamp(stamp_ns), "frame_id": parent}, "child_frame_id": child,
            "transform": {"translation": dict(zip("xyz", map(float, t))),
                          "rotation": dict(zip("xyzw", map(float, q)))}}


class Ros2LogWriter:
    """Write a ROS 2 MCAP log of an RGB-D camera (context manager; see the module doc for topics).

    ``image_transport``: 'raw' (sensor_msgs/Image) or 'compressed' (PNG in sensor_msgs/CompressedImage;
    depth in ROS ``compressedDepth`` form). ``pose_topic_kind``: 'pose' (PoseStamped on /camera/pose),
    'tf' (/tf + /tf_static chain) or 'both'. ``metadata`` goes into an MCAP metadata record ``zipon``.
    """

    def __init__(self, path, *, intrinsics: Intrinsics, image_transport: str = "raw", pose_topic_kind: str = "pose",
                 with_instance: bool = True, metadata: dict[str, str] | None = None, compression: str = "zstd"):
        from mcap.writer import CompressionType
        from mcap_ros2.writer import Writer

        if image_transport not in ("raw", "compressed"):
            raise ValueError(f"image_transport {image_transport!r}: expected 'raw' or 'compressed'")
        if pose_topic_kind not in ("pose", "tf", "both"):
            raise ValueError(f"pose_topic_kind {pose_topic_kind!r}: expected 'pose', 'tf' or 'both'")
        if compression not in ("zstd", "lz4"):
            raise ValueError(f"compression {compression!r}: expected 'zstd' or 'lz4'")
        self.path = Path(path)
        self.intrinsics = intrinsics
        self.image_transport = image_transport
        self.pose_topic_kind = pose_topic_kind
        self.with_instance = with_instance
        self._file = open(self.path, "wb")
        ctype = CompressionType.ZSTD if compression == "zstd" else CompressionType.LZ4
        self._writer = Writer(self._file, chunk_size=4 * 1024 * 1024, compression=ctype)
        self._schemas = {name: self._writer.register_msgdef(name, text) for name, text in MSGDEFS.items()}
        if metadata:
            self._writer.add_metadata("zipon", {str(k): str(v) for k, v in metadata.items()})
        self._static_written = False
        self._closed = False

    # -- context manager
    def __enter__(self) -> "Ros2LogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if not self._closed:
            self._writer.finish()
            self._file.close()
            self._closed = True

    def _write(self, topic: str, schema: str, msg: dict, stamp_ns: int) -> None:
        self._writer.write_message(topic, self._schemas[schema], msg, log_time=int(stamp_ns),
                                   publish_time=int(stamp_ns))

    def _header(self, stamp_ns: int, frame_id: str = OPTICAL_FRAME) -> dict:
        return {"stamp": _stamp(stamp_ns), "frame_id": frame_id}

    def _image(self, kind: str, stamp_ns: int, img: np.ndarray, encoding: str) -> None:
        h, w = img.shape[:2]
        if self.image_transport == "raw":
            msg = {"header": self._header(stamp_ns), "height": h, "width": w, "encoding": encoding,
                   "is_bigendian": 0, "step": int(img.strides[0]), "data": np.ascontiguousarray(img).tobytes()}
            self._write(TOPICS[kind], IMAGE, msg, stamp_ns)
            return
        if kind == "rgb":
            fmt, data = "rgb8; png compressed bgr8", _png(img[..., ::-1])
        elif kind == "depth":
            # compressed_depth_image_transport: ConfigHeader {int32 format; float depthParam[2]} + PNG.
            fmt, data = "16UC1; compressedDepth png", struct.pack("<iff", 0, 0.0, 0.0) + _png(img)
        else:
            fmt, data = "16UC1; png", _png(img)
        msg = {"header": self._header(stamp_ns), "format": fmt, "data": data}
        self._write(TOPICS[kind] + COMPRESSED_SUFFIX[kind], COMPRESSED, msg, stamp_ns)

    def write_frame(self, stamp_ns: int, rgb: np.ndarray, depth_mm: np.ndarray,
                    instance: np.ndarray | None = None) -> None:
        """Colour ``(H,W,3)`` uint8 RGB, depth ``(H,W)`` uint16 mm (0 = invalid), instance ``(H,W)`` uint16 ids,
        all stamped ``stamp_ns``; plus the CameraInfo of the colour camera."""
        intr = self.intrinsics
        h, w = intr.height, intr.width
        for name, arr, shape, dtype in (("rgb", rgb, (h, w, 3), np.uint8), ("depth_mm", depth_mm, (h, w), np.uint16),
                                        ("instance", instance, (h, w), np.uint16)):
            if arr is None:
                continue
            if arr.shape != shape or arr.dtype != dtype:
                raise ValueError(f"write_frame: {name} is {arr.dtype}{arr.shape}, expected {np.dtype(dtype)}{shape}")
        if self.with_instance and instance is None:
            raise ValueError("write_frame: this log records instance images (with_instance=True) but none was given")
        self._image("rgb", stamp_ns, rgb, "rgb8")
        self._image("depth", stamp_ns, depth_mm, "16UC1")
        if self.with_instance:
            self._image("instance", stamp_ns, instance, "16UC1")
        K = intr.K
        P = np.zeros((3, 4))
        P[:, :3] = K
        info = {"header": self._header(stamp_ns), "height": h, "width": w, "distortion_model": "plumb_bob",
                "d": [0.0] * 5, "k": K.ravel().tolist(), "r": np.eye(3).ravel().tolist(), "p": P.ravel().tolist(),
                "binning_x": 0, "binning_y": 0,
                "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}
        self._write(TOPICS["camera_info"], CAMERA_INFO, info, stamp_ns)

    def write_pose(self, stamp_ns: int, T_world_camera: np.ndarray) -> None:
        """Camera pose ``(4,4)`` float64 (optical camera -> z-up world) as PoseStamped and/or /tf."""
        T = np.asarray(T_world_camera, dtype=np.float64)
        if self.pose_topic_kind in ("pose", "both"):
            t, q = pose_to_tq(T)
            msg = {"header": self._header(stamp_ns, WORLD_FRAME),
                   "pose": {"position": dict(zip("xyz", map(float, t))),
                            "orientation": dict(zip("xyzw", map(float, q)))}}
            self._write(TOPICS["pose"], POSE_STAMPED, msg, stamp_ns)
        if self.pose_topic_kind in ("tf", "both"):
            if not self._static_written:
                static = [_transform_msg(stamp_ns, BASE_FRAME, CAMERA_LINK, _t_base_link()),
                          _transform_msg(stamp_ns, CAMERA_LINK, OPTICAL_FRAME, _t_link_optical())]
                self._write(TOPICS["tf_static"], TF, {"transforms": static}, stamp_ns)
                self._static_written = True
            T_odom_base = invert_pose(T_MAP_ODOM) @ T @ invert_pose(T_BASE_OPTICAL)
            msg = {"transforms": [_transform_msg(stamp_ns, WORLD_FRAME, ODOM_FRAME, T_MAP_ODOM),
                                  _transform_msg(stamp_ns, ODOM_FRAME, BASE_FRAME, T_odom_base)]}
            self._write(TOPICS["tf"], TF, msg, stamp_ns)

    def attach_ground_truth(self, gt) -> None:
        """Store a :class:`pipeline.scene_gt.GTScene` as the JSON attachment ``ground_truth.json``."""
        data = json.dumps(gt.model_dump(mode="json"), sort_keys=True).encode()
        self._writer.add_attachment(create_time=0, log_time=0, name="ground_truth.json",
                                    media_type="application/json", data=data)


def _png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"PNG encoding failed for an image {img.dtype}{img.shape}")
    return buf.tobytes()


# ----------------------------------------------------------------------------- fast CDR decoding

class _Cdr:
    """Little reader over a CDR buffer (alignment counted after the 4-byte encapsulation header)."""

    __slots__ = ("buf", "pos", "fmt")

    def __init__(self, buf: bytes):
        if len(buf) < 4 or buf[1] not in (0, 1):
            raise ValueError("not a CDR message (bad encapsulation header)")
        self.buf, self.pos = buf, 4
        self.fmt = "<" if buf[1] == 1 else ">"

    def _align(self, n: int) -> None:
        self.pos += (-(self.pos - 4)) % n

    def u32(self) -> int:
        self._align(4)
        (v,) = struct.unpack_from(self.fmt + "I", self.buf, self.pos)
        self.pos += 4
        return v

    def i32(self) -> int:
        self._align(4)
        (v,) = struct.unpack_from(self.fmt + "i", self.buf, self.pos)
        self.pos += 4
        return v

    def u8(self) -> int:
        v = self.buf[self.pos]
        self.pos += 1
        return v

    def string(self) -> str:
        n = self.u32()
        s = bytes(self.buf[self.pos : self.pos + n]).rstrip(b"\0").decode()
        self.pos += n
        return s

    def blob(self) -> memoryview:
        n = self.u32()
        if self.pos + n > len(self.buf):
            raise ValueError(f"byte sequence of {n} bytes runs past the end of the message")
        v = memoryview(self.buf)[self.pos : self.pos + n]
        self.pos += n
        return v

    def header(self) -> tuple[int, str]:
        sec = self.i32()
        nsec = self.u32()
        return sec * 1_000_000_000 + nsec, self.string()


def parse_image_cdr(data: bytes) -> dict:
    """sensor_msgs/Image CDR -> dict(stamp_ns, frame_id, height, width, encoding, is_bigendian, step, data)."""
    r = _Cdr(data)
    stamp, frame_id = r.header()
    h, w = r.u32(), r.u32()
    enc = r.string()
    big = r.u8()
    step = r.u32()
    return {"stamp_ns": stamp, "frame_id": frame_id, "height": h, "width": w, "encoding": enc,
            "is_bigendian": big, "step": step, "data": r.blob()}


def parse_compressed_cdr(data: bytes) -> dict:
    """sensor_msgs/CompressedImage CDR -> dict(stamp_ns, frame_id, format, data)."""
    r = _Cdr(data)
    stamp, frame_id = r.header()
    fmt = r.string()
    return {"stamp_ns": stamp, "frame_id": frame_id, "format": fmt, "data": r.blob()}


def raw_image_to_array(msg: dict, *, where: dict) -> np.ndarray:
    """A parsed Image -> ``(H,W)`` or ``(H,W,C)`` array of its encoding's dtype (RGB order for colour).

    bgr/bgra are reordered to RGB; alpha is dropped; mono8 becomes grey RGB. ``where`` (path, topic,
    frame) goes into any :class:`InputDataError`.
    """
    enc = msg["encoding"]
    if enc not in RAW_ENCODINGS:
        raise InputDataError(f"unknown image encoding {enc!r}", field="encoding", **where,
                             expected=f"one of {sorted(RAW_ENCODINGS)}")
    dt, ch = RAW_ENCODINGS[enc]
    dtype = np.dtype(dt).newbyteorder(">" if msg["is_bigendian"] else "<")
    h, w, step = msg["height"], msg["width"], msg["step"]
    row = w * ch * dtype.itemsize
    if step < row or len(msg["data"]) < step * h:
        raise InputDataError(f"image data holds {len(msg['data'])} bytes with step {step}", field="data", **where,
                             expected=f"at least {h} rows of {row} bytes for {w}x{h} {enc}")
    buf = np.frombuffer(msg["data"], dtype=np.uint8, count=step * h).reshape(h, step)[:, :row]
    arr = buf.copy().view(dtype).reshape((h, w, ch) if ch > 1 else (h, w))
    arr = arr.astype(dtype.newbyteorder("="), copy=False)
    if enc.startswith("bgr"):
        arr = arr[..., [2, 1, 0]]
    elif enc == "rgba8":
        arr = arr[..., :3]
    elif enc == "mono8":
        arr = np.repeat(arr[..., None], 3, axis=-1)
    return np.ascontiguousarray(arr)


def compressed_image_to_array(msg: dict, *, where: dict) -> np.ndarray:
    """A parsed CompressedImage -> array: colour ``(H,W,3)`` uint8 RGB; 16-bit PNG ``(H,W)`` uint16;
    ``compressedDepth`` 16UC1 ``(H,W)`` uint16 mm or 32FC1 ``(H,W)`` float32 metres."""
    fmt = msg["format"]
    data = bytes(msg["data"])
    low = fmt.lower()
    if "compresseddepth" in low:
        at = data.find(PNG_MAGIC)
        if at < 0:
            raise InputDataError("compressedDepth image without a PNG payload", field="format", **where,
                                 expected="a ConfigHeader followed by PNG data ('16UC1; compressedDepth png')")
        img = decode_image(data[at:], cv2.IMREAD_UNCHANGED, what="compressedDepth", field="data", **where)
        if img.dtype != np.uint16:
            raise InputDataError("compressedDepth PNG could not be decoded as 16-bit", field="data", **where)
        if low.startswith("32fc1"):
            # Inverse-depth quantisation: depth = A / (v - B), v = 0 invalid.
            if at < 12:
                raise InputDataError("32FC1 compressedDepth without its ConfigHeader", field="data", **where)
            _, a, b = struct.unpack_from("<iff", data, at - 12)
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = np.where(img > 0, a / (img.astype(np.float32) - b), np.nan)
            return depth.astype(np.float32)
        return img
    if not any(k in low for k in ("png", "jpeg", "jpg")):
        raise InputDataError(f"unknown compressed image format {fmt!r}", field="format", **where,
                             expected="png or jpeg (image_transport 'compressed'), or '16UC1; compressedDepth'")
    img = decode_image(data, cv2.IMREAD_UNCHANGED, what=f"{fmt!r}", field="data", **where)
    if img.ndim == 2 and img.dtype == np.uint16:
        return img
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=-1)
    # OpenCV decodes to BGR(A), whatever the declared source encoding.
    return np.ascontiguousarray(img[..., [2, 1, 0]])
