"""ROS logs of an RGB-D camera, whatever the container: the logic every ROS reader shares.

A :class:`RosLogReader` finds its topics, intrinsics, pose chain and depth registration and streams
:class:`~pipeline.readers.base.Sample` s; it reads messages only through a :class:`MessageSource`
(the container: MCAP through the ``mcap`` library in :mod:`pipeline.readers.mcap`, ROS 1 ``.bag`` and
ROS 2 ``.db3``/``.mcap`` through ``rosbags`` in :mod:`pipeline.readers.rosbag`). So topic detection,
time matching (:mod:`pipeline.readers.matcher`) and the tf logic exist once.

Streams: colour ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) or ``CompressedImage``
(png/jpeg); depth Image 16UC1 (mm) / 32FC1 (m) or CompressedImage ``compressedDepth`` / 16-bit png;
an optional 16UC1 instance topic; intrinsics from ``sensor_msgs/CameraInfo`` (K, width, height;
checked constant); the camera pose from a ``geometry_msgs/PoseStamped`` topic or the ``/tf`` +
``/tf_static`` chain from the world frame (auto: the tree's root) to the camera's optical frame
(auto: the colour images' ``header.frame_id``), each dynamic link interpolated on its own. Images
are decoded only when matched; stamps are header stamps (the log time when a header stamp is zero).

Depth on another camera than colour (another ``frame_id``, or a depth CameraInfo with other K or
size) is registered into the colour camera (:mod:`pipeline.readers.registration`) with the static
tf between the two optical frames; without that tf the log is refused naming both topics. Depth is
never silently assumed aligned.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics, invert_pose
from pipeline.readers.base import (DEPTH, INSTANCE, POSE, RGB, Opened, PoseLink, Reader, Sample, SourceInfo,
                                   pose_from_tq_checked)
from pipeline.readers.registration import DepthRegistration
from pipeline.ros2 import (CAMERA_INFO, COMPRESSED, IMAGE, POSE_STAMPED, RAW_ENCODINGS, TF,
                           compressed_image_to_array, raw_image_to_array)

_NAME_HINTS = {
    DEPTH: ("depth",),
    INSTANCE: ("instance", "semantic", "segment", "panoptic"),
}
_NOT_COLOUR = ("depth", "instance", "semantic", "segment", "panoptic", "infra", "ir/", "mask", "confidence",
               "disparity")
_TF_PREAMBLE_NS = 2_000_000_000  # /tf read ahead to learn the frame tree


class MessageSource(ABC):
    """One ROS log container, read-only: topics with their ROS 2 type names, raw messages, decoding.

    ``types`` maps topic -> type name (``sensor_msgs/msg/Image``); ``counts`` topic -> messages;
    ``start_ns`` the first log time. Errors raise :class:`InputDataError` naming ``file``.
    """

    file: Path
    types: dict[str, str]
    counts: dict[str, int]
    start_ns: int

    @abstractmethod
    def messages(self, topics: list[str], stop_ns: int | None = None) -> Iterator[tuple[str, int, Any]]:
        """``(topic, log_time_ns, raw)`` in log-time order for ``topics``, log time < ``stop_ns`` if given."""

    @abstractmethod
    def decode(self, topic: str, raw: Any, index: int) -> Any:
        """A message with attribute access (ROS 1 and ROS 2 field names as the bag defines them)."""

    @abstractmethod
    def image(self, topic: str, raw: Any, index: int) -> dict:
        """An Image as dict(stamp_ns, frame_id, height, width, encoding, is_bigendian, step, data), or a
        CompressedImage as dict(stamp_ns, frame_id, format, data); undecoded pixels."""

    def ground_truth_json(self) -> bytes | None:
        """A ``ground_truth.json`` attachment (zipon's simulator), if the container has attachments."""
        return None

    def metadata(self) -> dict:
        """Container metadata records, for provenance (keys merged into the frame store's provenance)."""
        return {}

    def close(self) -> None:
        """Release file handles (readers are closed when the ingest ends)."""


def _field(msg, *names):
    """The first present attribute of ``names`` (ROS 2 lowercase / ROS 1 uppercase CameraInfo fields)."""
    for n in names:
        if hasattr(msg, n):
            return getattr(msg, n)
    raise AttributeError(names[0])


@dataclass(frozen=True)
class RosLogStreams:
    """The opened log: its container (closed when the stream ends), the topic of each stream (``rgb``, ``depth``,
    ``camera_info``, ``instance`` when there is one), the pose topics with their types, the pose chain, the colour
    camera and the depth registration into it (None: depth on the colour camera)."""

    src: MessageSource
    topics: dict[str, str]
    pose_topics: dict[str, str]
    chain: list[PoseLink]
    intrinsics: Intrinsics
    registration: DepthRegistration | None


class RosLogReader(Reader):
    """See the module doc. Subclasses provide :meth:`_source`; topic names come from ``params.topics`` or
    are detected by type and name (:class:`LogScan`)."""

    @abstractmethod
    def _source(self) -> MessageSource:
        """Open the container."""

    def open(self) -> Opened[RosLogStreams]:
        scan = LogScan(self._source(), self.params)
        t = self.params.topics
        rgb = scan.pick(RGB, t.rgb)
        depth = scan.pick(DEPTH, t.depth)
        instance = scan.pick(INSTANCE, t.instance, required=False)
        info_topic = scan.pick_info(t.camera_info, rgb)
        topics = {RGB: rgb, DEPTH: depth, "camera_info": info_topic}
        if instance:
            topics[INSTANCE] = instance
        intrinsics, info0 = scan.camera_info(info_topic)
        chain, pose_where, pose_desc, pose_topics = scan.pose_chain(rgb)
        registration, depth_desc = scan.depth_registration(rgb, depth, info_topic, intrinsics)
        gt = scan.ground_truth()
        where = {RGB: rgb, DEPTH: depth, **({INSTANCE: instance} if instance else {}), **pose_where}
        d, model = [float(x) for x in _field(info0, "d", "D")], str(info0.distortion_model)
        info = SourceInfo(
            intrinsics=intrinsics, has_instance=bool(instance), pose_chain=chain, where=where, ground_truth=gt,
            provenance={
                "topics": {**topics, "pose": pose_desc},
                "message_types": {k: scan.types[k] for k in topics.values()},
                "conversions": [
                    "stamps: header.stamp (log time if zero)",
                    "colour: bgr/bgra/rgba/mono reordered to RGB uint8; compressed png/jpeg decoded with OpenCV",
                    "depth: 16UC1 kept as mm; 32FC1 metres -> mm (rounded); compressedDepth PNG decoded",
                    f"depth: {depth_desc}",
                    "intrinsics: CameraInfo k (3x3), width, height; distortion ignored",
                    f"pose: {pose_desc}",
                ],
                "camera_info_distortion": {"model": model, "d": d},
                **scan.src.metadata(),
                "messages_per_topic": {k: scan.src.counts.get(k, 0) for k in sorted(set(topics.values()))},
            },
        )
        return Opened(info, RosLogStreams(src=scan.src, topics=topics, pose_topics=pose_topics, chain=chain,
                                          intrinsics=intrinsics, registration=registration))

    def samples(self, opened: Opened[RosLogStreams]) -> Iterator[Sample]:
        log = opened.state
        src = log.src
        image_topics = {log.topics[s]: s for s in (RGB, DEPTH, INSTANCE) if s in log.topics}
        info_topic = log.topics["camera_info"]
        dynamic = {lk.name for lk in log.chain if lk.static is None}
        index: dict[str, int] = {}
        topics = list(dict.fromkeys(list(image_topics) + [info_topic] + list(log.pose_topics)))
        try:
            for topic, log_time, raw in src.messages(topics):
                i = index[topic] = index.get(topic, -1) + 1
                if topic in image_topics:
                    yield _image_sample(log, image_topics[topic], topic, raw, log_time, i)
                elif topic == info_topic:
                    _check_info(log, raw, i)
                elif log.pose_topics.get(topic) == POSE_STAMPED:
                    m = _decode(src, POSE_STAMPED, raw, topic, i)
                    p, q = m.pose.position, m.pose.orientation
                    T = pose_from_tq_checked([p.x, p.y, p.z, q.x, q.y, q.z, q.w], path=src.file, topic=topic,
                                             frame=i, field="pose")
                    yield Sample(POSE, _stamp(m.header.stamp, log_time), i, T, key="world->camera", rigid=True)
                elif topic == "/tf":
                    for tr in _decode(src, TF, raw, topic, i).transforms:
                        name = f"{tr.header.frame_id}->{tr.child_frame_id}"
                        if name in dynamic:
                            yield Sample(POSE, _stamp(tr.header.stamp, log_time), i, _tf_pose(src, tr, topic, i),
                                         key=name, rigid=True)
        finally:
            src.close()


# ---------------------------------------------------------------------- reading messages

def _decode(src: MessageSource, type_name: str, raw, topic: str, index: int):
    try:
        return src.decode(topic, raw, index)
    except InputDataError:
        raise
    except Exception as err:  # noqa: BLE001 - any decoder failure is this message's finding
        raise InputDataError(f"message could not be decoded as {type_name} ({err})", path=src.file,
                             topic=topic, frame=index) from None


def _parse_image(src: MessageSource, topic: str, raw, i: int) -> dict:
    try:
        return src.image(topic, raw, i)
    except InputDataError:
        raise
    except (ValueError, IndexError, UnicodeDecodeError, AttributeError) as err:
        raise InputDataError(f"message is not a valid {src.types[topic]} ({err})", path=src.file, topic=topic,
                             frame=i) from None


def _tf_pose(src: MessageSource, tr, topic: str, index: int) -> np.ndarray:
    tt, q = tr.transform.translation, tr.transform.rotation
    return pose_from_tq_checked([tt.x, tt.y, tt.z, q.x, q.y, q.z, q.w], path=src.file, topic=topic, frame=index,
                                field=f"transforms[{tr.header.frame_id}->{tr.child_frame_id}]")


def _stamp(stamp, log_time: int) -> int:
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return ns if ns else int(log_time)


def _image_sample(log: RosLogStreams, stream: str, topic: str, raw, log_time: int, i: int) -> Sample:
    where = {"path": log.src.file, "topic": topic, "frame": i}
    m = _parse_image(log.src, topic, raw, i)
    stamp = m["stamp_ns"] or int(log_time)
    reg = log.registration if stream == DEPTH else None
    if log.src.types[topic] == IMAGE:
        if m["encoding"] not in RAW_ENCODINGS:
            raise InputDataError(f"unknown image encoding {m['encoding']!r}", **where, field="encoding",
                                 expected=f"one of {sorted(RAW_ENCODINGS)}")
        intr = reg.depth if reg else log.intrinsics
        if (m["width"], m["height"]) != (intr.width, intr.height):
            info = log.topics["camera_info"] if reg is None else "of the depth camera"
            raise InputDataError(f"image is {m['width']}x{m['height']}", **where, field="width/height",
                                 expected=f"{intr.width}x{intr.height} as in CameraInfo {info}")
        decode = lambda: raw_image_to_array(m, where=where)  # noqa: E731
    else:
        decode = lambda: compressed_image_to_array(m, where=where)  # noqa: E731
    return Sample(stream, stamp, i, (lambda: reg(decode())) if reg else decode)


def _check_info(log: RosLogStreams, raw, i: int) -> None:
    topic = log.topics["camera_info"]
    info = _decode(log.src, CAMERA_INFO, raw, topic, i)
    K = np.asarray(_field(info, "k", "K"), dtype=np.float64).reshape(3, 3)
    if (info.width, info.height) != (log.intrinsics.width, log.intrinsics.height) or not np.allclose(
            K, log.intrinsics.K, rtol=0, atol=1e-9):
        raise InputDataError(f"CameraInfo changed to {info.width}x{info.height}, K {K.tolist()}", path=log.src.file,
                             topic=topic, field="k/width/height", frame=i,
                             expected=f"constant intrinsics as in message 0 ({log.intrinsics.to_dict()})")


# ---------------------------------------------------------------------- what opening a log finds

class LogScan:
    """What :meth:`RosLogReader.open` looks up in one log: topics, CameraInfo, the tf tree (read once, when first
    needed), the pose chain, the depth registration and the ground truth. It lives only while the log is opened."""

    def __init__(self, src: MessageSource, params: IngestParams):
        self.src, self.params = src, params
        self.file, self.types = src.file, src.types
        self._tree: dict | None = None

    def missing(self, what: str, field: str, candidates: list[str]) -> InputDataError:
        listing = ", ".join(f"{k} ({self.types[k]})" for k in sorted(self.types)) or "none"
        msg = f"no {what} topic" if not candidates else f"several {what} topics: {', '.join(candidates)}"
        return InputDataError(f"{msg}; topics in the log: {listing}", path=self.file, field=f"ingest.topics.{field}",
                              expected=f"one {what} topic (set ingest.topics.{field})")

    def pick(self, stream: str, given: str | None, required: bool = True) -> str | None:
        images = [k for k, v in self.types.items() if v in (IMAGE, COMPRESSED)]
        if given:
            if given not in self.types:
                raise InputDataError(f"topic {given!r} is not in the log", path=self.file, topic=given,
                                     field=f"ingest.topics.{stream}", expected=f"one of {sorted(self.types)}")
            if self.types[given] not in (IMAGE, COMPRESSED):
                raise InputDataError(f"topic has type {self.types[given]}", path=self.file, topic=given,
                                     expected="sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage")
            return given
        if stream == RGB:
            cands = [k for k in images if not any(h in k.lower() for h in _NOT_COLOUR)]
            if len(cands) > 1:
                cands = [k for k in cands if any(h in k.lower() for h in ("color", "colour", "rgb"))] or cands
        else:
            cands = [k for k in images if any(h in k.lower() for h in _NAME_HINTS[stream])]
            if stream == DEPTH:
                cands = [k for k in cands if "disparity" not in k.lower()]
                # RealSense with align_depth: the depth already registered to colour needs no registration
                cands = [k for k in cands if "aligned" in k.lower()] or cands
        if len(cands) > 1:  # both raw and compressed of one camera: prefer raw (lossless, no decode)
            raw = [k for k in cands if self.types[k] == IMAGE]
            cands = raw if len(raw) == 1 else cands
        if len(cands) == 1:
            return cands[0]
        if not cands and not required:
            return None
        what = {RGB: "colour image", DEPTH: "depth image", INSTANCE: "instance image"}[stream]
        raise self.missing(what, stream, cands)

    def infos(self) -> list[str]:
        return [k for k, v in self.types.items() if v == CAMERA_INFO]

    @staticmethod
    def info_near(image_topic: str, infos: list[str]) -> str | None:
        """The CameraInfo in the closest namespace above ``image_topic`` holding exactly one."""
        parts = image_topic.split("/")
        for cut in range(len(parts) - 1, 0, -1):
            ns = "/".join(parts[:cut]) + "/"
            near = [k for k in infos if k.startswith(ns)]
            if len(near) == 1:
                return near[0]
            if near:
                return None
        return None

    def pick_info(self, given: str | None, rgb: str) -> str:
        infos = self.infos()
        if given:
            if self.types.get(given) != CAMERA_INFO:
                raise InputDataError("not a CameraInfo topic in the log", path=self.file, topic=given,
                                     field="ingest.topics.camera_info", expected=f"one of {infos}")
            return given
        found = infos[0] if len(infos) == 1 else self.info_near(rgb, infos)
        if found is None:
            raise self.missing("sensor_msgs/CameraInfo", "camera_info", infos)
        return found

    def camera_info(self, topic: str) -> tuple[Intrinsics, Any]:
        for _, _, raw in self.src.messages([topic]):
            info = _decode(self.src, CAMERA_INFO, raw, topic, 0)
            K = np.asarray(_field(info, "k", "K"), dtype=np.float64).reshape(3, 3)
            if info.width == 0 or info.height == 0 or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
                raise InputDataError(f"CameraInfo has width {info.width}, height {info.height}, K {K.tolist()}",
                                     path=self.file, topic=topic, field="k", frame=0,
                                     expected="positive image size and focal lengths")
            return Intrinsics.from_K(K, info.width, info.height), info
        raise InputDataError("CameraInfo topic has no messages", path=self.file, topic=topic,
                             expected="at least one sensor_msgs/CameraInfo")

    # ------------------------------------------------------------------ tf
    def tf_tree(self) -> dict[str, tuple[str, np.ndarray | None]]:
        """child frame -> (parent frame, static transform or None for /tf links), from /tf_static and the
        first seconds of /tf."""
        if self._tree is not None:
            return self._tree
        parent: dict[str, tuple[str, np.ndarray | None]] = {}
        if "/tf_static" in self.types:
            for i, (_, _, raw) in enumerate(self.src.messages(["/tf_static"])):
                for tr in _decode(self.src, TF, raw, "/tf_static", i).transforms:
                    parent[tr.child_frame_id] = (tr.header.frame_id, _tf_pose(self.src, tr, "/tf_static", i))
        if "/tf" in self.types:
            for i, (_, _, raw) in enumerate(self.src.messages(["/tf"], self.src.start_ns + _TF_PREAMBLE_NS)):
                for tr in _decode(self.src, TF, raw, "/tf", i).transforms:
                    parent.setdefault(tr.child_frame_id, (tr.header.frame_id, None))
        self._tree = parent
        return parent

    def pose_chain(self, rgb: str) -> tuple[list[PoseLink], dict[str, str], str, dict[str, str]]:
        """The chain world -> camera, where each link comes from, in words, and the pose topics with their types."""
        t = self.params.topics
        stamped = [k for k, v in self.types.items() if v == POSE_STAMPED]
        use_tf = t.tf_camera_frame is not None or t.tf_world_frame is not None
        if t.pose or (not use_tf and stamped):
            topic = t.pose or (stamped[0] if len(stamped) == 1 else None)
            if topic is None:
                raise self.missing("geometry_msgs/PoseStamped", "pose", stamped)
            if self.types.get(topic) != POSE_STAMPED:
                raise InputDataError("not a PoseStamped topic in the log", path=self.file, topic=topic,
                                     field="ingest.topics.pose", expected=f"one of {stamped}")
            link = PoseLink("world", "camera")
            return ([link], {link.name: topic}, f"geometry_msgs/PoseStamped on {topic} (header.frame_id -> camera)",
                    {topic: POSE_STAMPED})
        if "/tf" not in self.types:
            raise InputDataError("no camera pose in the log", path=self.file, field="ingest.topics.pose",
                                 expected="a geometry_msgs/PoseStamped topic or /tf (tf2_msgs/TFMessage)")
        camera = t.tf_camera_frame or self.first_frame_id(rgb)
        parent = self.tf_tree()
        if camera not in parent:
            raise InputDataError(f"camera frame {camera!r} is not in the tf tree (frames: {sorted(parent)})",
                                 path=self.file, topic="/tf", field="ingest.topics.tf_camera_frame",
                                 expected="the colour images' frame_id as a /tf or /tf_static child frame")
        chain, frame = [], camera
        while frame in parent and frame != t.tf_world_frame:
            p, static = parent[frame]
            chain.append(PoseLink(p, frame, static))
            frame = p
        if t.tf_world_frame and frame != t.tf_world_frame:
            raise InputDataError(f"tf chain from {camera!r} ends at {frame!r}", path=self.file, topic="/tf",
                                 field="ingest.topics.tf_world_frame", expected=f"a chain up to {t.tf_world_frame!r}")
        chain.reverse()
        pose_topics = {k: TF for k in ("/tf", "/tf_static") if k in self.types}
        names = " -> ".join([chain[0].parent] + [lk.child for lk in chain])
        where = {lk.name: ("/tf_static" if lk.static is not None else "/tf") for lk in chain}
        return chain, where, f"tf chain {names} (static links from /tf_static; dynamic links interpolated)", pose_topics

    def static_between(self, target: str, source: str) -> np.ndarray | None:
        """``T_target_source`` from static tf links only (both frames up to a common ancestor), else None."""
        parent = self.tf_tree()

        def to_ancestors(frame: str) -> dict[str, np.ndarray] | None:
            out, T = {frame: np.eye(4)}, np.eye(4)
            while frame in parent:
                p, static = parent[frame]
                if static is None:
                    break
                T = static @ T
                frame = p
                out[frame] = T
            return out

        a, b = to_ancestors(target), to_ancestors(source)
        common = [f for f in a if f in b]
        if not common:
            return None
        return invert_pose(a[common[0]]) @ b[common[0]]

    def first_frame_id(self, topic: str) -> str:
        for i, (_, _, raw) in enumerate(self.src.messages([topic])):
            return _parse_image(self.src, topic, raw, i)["frame_id"]
        raise InputDataError("image topic has no messages", path=self.file, topic=topic, expected="images")

    # ------------------------------------------------------------------ depth registration
    def depth_registration(self, rgb: str, depth: str, info_topic: str, colour: Intrinsics
                           ) -> tuple[DepthRegistration | None, str]:
        given = self.params.topics.depth_camera_info
        infos = [k for k in self.infos() if k != info_topic]
        if given and self.types.get(given) != CAMERA_INFO:
            raise InputDataError("not a CameraInfo topic in the log", path=self.file, topic=given,
                                 field="ingest.topics.depth_camera_info", expected=f"one of {infos}")
        depth_info = given or self.info_near(depth, infos)
        rgb_frame, depth_frame = self.first_frame_id(rgb), self.first_frame_id(depth)
        K_depth = None
        if depth_info:
            K_depth, _ = self.camera_info(depth_info)
        same_frame = depth_frame == rgb_frame or not depth_frame
        if same_frame and (K_depth is None or K_depth == colour):
            how = f"on the colour camera (frame_id {rgb_frame!r}"
            return None, how + (f", CameraInfo {depth_info} equal to colour's)" if depth_info else ")")
        if K_depth is None:
            raise InputDataError(
                f"depth is on frame {depth_frame!r}, colour on {rgb_frame!r}, and the depth camera has no CameraInfo",
                path=self.file, topic=f"{depth} and {rgb}", field="ingest.topics.depth_camera_info",
                expected="the depth camera's sensor_msgs/CameraInfo (set ingest.topics.depth_camera_info) to "
                         "register depth into colour, or depth aligned to colour (aligned_depth_to_color)")
        T = np.eye(4) if same_frame else self.static_between(rgb_frame, depth_frame)
        if T is None:
            raise InputDataError(
                f"depth (frame {depth_frame!r}) is not aligned to colour (frame {rgb_frame!r}) and no static tf "
                "links the two frames", path=self.file, topic=f"{depth} and {rgb}",
                expected="/tf_static transforms between the depth and colour optical frames, or depth aligned "
                         "to colour (aligned_depth_to_color)")
        reg = DepthRegistration(K_depth, colour, T)
        return reg, f"{reg.describe()} (CameraInfo {depth_info}, tf {depth_frame} -> {rgb_frame})"

    # ------------------------------------------------------------------ ground truth
    def ground_truth(self) -> dict | None:
        from pipeline.scene_gt import GTScene

        data = self.src.ground_truth_json()
        if data is None:
            return None
        try:
            return GTScene.model_validate(json.loads(data)).model_dump(mode="json")
        except ValueError as err:  # bad JSON, bad UTF-8 and pydantic's ValidationError are all ValueErrors
            raise InputDataError(f"ground_truth.json attachment is invalid: {err}", path=self.file,
                                 field="attachment ground_truth.json", expected="a GTScene JSON document") from None
