"""ROS 2 MCAP logs (``mcap`` + ``mcap_ros2``; no ROS installation needed).

Streams: colour ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) or ``CompressedImage``
(png/jpeg); depth Image 16UC1 (mm) / 32FC1 (m) or CompressedImage ``compressedDepth`` / 16-bit png;
an optional 16UC1 instance topic; intrinsics from ``sensor_msgs/CameraInfo`` (K, width, height;
checked constant); the camera pose from a ``geometry_msgs/PoseStamped`` topic or the ``/tf`` +
``/tf_static`` chain from the world frame (auto: the tree's root) to the camera's optical frame
(auto: the colour images' ``header.frame_id``), each dynamic link interpolated on its own.
Images are parsed from CDR with numpy (the layout is fixed) and decoded only when matched; stamps
are header stamps (the log time when a header stamp is zero). A ``ground_truth.json`` attachment
(:class:`pipeline.scene_gt.GTScene`) is carried into the frame store.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import Intrinsics
from pipeline.readers.base import (DEPTH, INSTANCE, POSE, RGB, PoseLink, Reader, Sample, SourceInfo,
                                   pose_from_tq_checked, register)
from pipeline.ros2 import (CAMERA_INFO, COMPRESSED, IMAGE, POSE_STAMPED, TF, compressed_image_to_array,
                           parse_compressed_cdr, parse_image_cdr, raw_image_to_array)

_NAME_HINTS = {
    DEPTH: ("depth",),
    INSTANCE: ("instance", "semantic", "segment", "panoptic"),
}
_NOT_COLOUR = ("depth", "instance", "semantic", "segment", "panoptic", "infra", "ir/", "mask", "confidence",
               "disparity")
_TF_PREAMBLE_NS = 2_000_000_000  # /tf read ahead to learn the frame tree


def _corrupt(path, err: Exception) -> InputDataError:
    return InputDataError(f"not a readable MCAP log (truncated or corrupt: {type(err).__name__}: {err})", path=path,
                          expected="a complete MCAP file with a summary section (repair with `mcap recover`)")


@register("mcap")
class McapReader(Reader):
    """See the module doc. Topic names come from ``params.topics`` or are detected by type and name."""

    @classmethod
    def detect(cls, path: Path) -> bool:
        return cls._log_file(path) is not None

    @staticmethod
    def _log_file(path: Path) -> Path | None:
        if path.is_file():
            with open(path, "rb") as f:
                return path if f.read(5) == b"\x89MCAP" or path.suffix == ".mcap" else None
        if path.is_dir():  # a rosbag2 folder: metadata.yaml + one .mcap
            logs = sorted(path.glob("*.mcap"))
            return logs[0] if len(logs) == 1 else None
        return None

    # ------------------------------------------------------------------ open
    def open(self) -> SourceInfo:
        from mcap.reader import make_reader

        self.file = self._log_file(self.path) or self.path
        try:
            self._stream = open(self.file, "rb")
            self._reader = make_reader(self._stream, validate_crcs=True)
            summary = self._reader.get_summary()
        except Exception as err:  # mcap raises McapError, struct.error, EndOfFile, ValueError...
            raise _corrupt(self.file, err) from None
        if summary is None or not summary.chunk_indexes and summary.statistics and summary.statistics.message_count:
            raise InputDataError("log has no summary/chunk index", path=self.file,
                                 expected="an indexed MCAP file (repair with `mcap recover`)")
        self.summary = summary
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        self.types: dict[str, str] = {}
        self.count: dict[str, int] = {}
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
            self.types[ch.topic] = schema.name if schema else "(no schema)"
            self.count[ch.topic] = self.count.get(ch.topic, 0) + int(counts.get(ch.id, 0))
        t = self.params.topics
        rgb = self._pick(RGB, t.rgb)
        depth = self._pick(DEPTH, t.depth)
        instance = self._pick(INSTANCE, t.instance, required=False)
        info_topic = self._pick_info(t.camera_info, rgb)
        self.topics = {RGB: rgb, DEPTH: depth, "camera_info": info_topic}
        if instance:
            self.topics[INSTANCE] = instance
        self.intrinsics, self._info0 = self._first_camera_info(info_topic)
        chain, pose_where, pose_desc = self._pose_chain(rgb)
        self.chain = chain
        gt = self._ground_truth()
        meta = {}
        try:
            for m in self._reader.iter_metadata():
                meta[m.name] = dict(m.metadata)
        except Exception as err:
            raise _corrupt(self.file, err) from None
        where = {RGB: rgb, DEPTH: depth, **({INSTANCE: instance} if instance else {}), **pose_where}
        return SourceInfo(
            intrinsics=self.intrinsics, has_instance=bool(instance), pose_chain=chain, where=where, ground_truth=gt,
            provenance={
                "topics": {**{k: v for k, v in self.topics.items()}, "pose": pose_desc},
                "message_types": {k: self.types[k] for k in self.topics.values()},
                "conversions": [
                    "stamps: header.stamp (log time if zero)",
                    "colour: bgr/bgra/rgba/mono reordered to RGB uint8; compressed png/jpeg decoded with OpenCV",
                    "depth: 16UC1 kept as mm; 32FC1 metres -> mm (rounded); compressedDepth PNG decoded",
                    "intrinsics: CameraInfo k (3x3), width, height; distortion ignored",
                    f"pose: {pose_desc}",
                ],
                "camera_info_distortion": {"model": self._info0.distortion_model, "d": list(self._info0.d)},
                "mcap_metadata": meta,
                "log_time_range_ns": [int(summary.statistics.message_start_time),
                                      int(summary.statistics.message_end_time)] if summary.statistics else None,
            },
        )

    def _missing(self, what: str, field: str, candidates: list[str]) -> InputDataError:
        listing = ", ".join(f"{k} ({self.types[k]})" for k in sorted(self.types)) or "none"
        msg = f"no {what} topic" if not candidates else f"several {what} topics: {', '.join(candidates)}"
        return InputDataError(f"{msg}; topics in the log: {listing}", path=self.file, field=f"ingest.topics.{field}",
                              expected=f"one {what} topic (set ingest.topics.{field})")

    def _pick(self, stream: str, given: str | None, required: bool = True) -> str | None:
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
        if len(cands) > 1:  # both raw and compressed of one camera: prefer raw (lossless, no decode)
            raw = [k for k in cands if self.types[k] == IMAGE]
            cands = raw if len(raw) == 1 else cands
        if len(cands) == 1:
            return cands[0]
        if not cands and not required:
            return None
        what = {RGB: "colour image", DEPTH: "depth image", INSTANCE: "instance image"}[stream]
        raise self._missing(what, stream, cands)

    def _pick_info(self, given: str | None, rgb: str) -> str:
        infos = [k for k, v in self.types.items() if v == CAMERA_INFO]
        if given:
            if self.types.get(given) != CAMERA_INFO:
                raise InputDataError("not a CameraInfo topic in the log", path=self.file, topic=given,
                                     field="ingest.topics.camera_info", expected=f"one of {infos}")
            return given
        if len(infos) > 1:
            ns = rgb.rsplit("/", 2)[0]
            infos = [k for k in infos if k.startswith(ns + "/")] or infos
        if len(infos) != 1:
            raise self._missing("sensor_msgs/CameraInfo", "camera_info", infos)
        return infos[0]

    def _decoder(self, schema_name: str):
        from mcap_ros2._dynamic import generate_dynamic

        cache = self.__dict__.setdefault("_decoders", {})
        if schema_name not in cache:
            schema = next(s for s in self.summary.schemas.values() if s.name == schema_name)
            cache[schema_name] = generate_dynamic(schema.name, schema.data.decode())[schema.name]
        return cache[schema_name]

    def _messages(self, topics: list[str], **kw):
        try:
            yield from self._reader.iter_messages(topics=topics, **kw)
        except InputDataError:
            raise
        except Exception as err:
            raise _corrupt(self.file, err) from None

    def _decode(self, schema_name: str, data: bytes, topic: str, index: int):
        try:
            return self._decoder(schema_name)(data)
        except Exception as err:
            raise InputDataError(f"message could not be decoded as {schema_name} ({err})", path=self.file,
                                 topic=topic, frame=index) from None

    def _first_camera_info(self, topic: str):
        for _, _, msg in self._messages([topic]):
            info = self._decode(CAMERA_INFO, msg.data, topic, 0)
            K = np.asarray(info.k, dtype=np.float64).reshape(3, 3)
            if info.width == 0 or info.height == 0 or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
                raise InputDataError(f"CameraInfo has width {info.width}, height {info.height}, K {K.tolist()}",
                                     path=self.file, topic=topic, field="k", frame=0,
                                     expected="positive image size and focal lengths")
            return Intrinsics.from_K(K, info.width, info.height), info
        raise InputDataError("CameraInfo topic has no messages", path=self.file, topic=topic,
                             expected="at least one sensor_msgs/CameraInfo")

    def _pose_chain(self, rgb: str) -> tuple[list[PoseLink], dict[str, str], str]:
        t = self.params.topics
        stamped = [k for k, v in self.types.items() if v == POSE_STAMPED]
        use_tf = t.tf_camera_frame is not None or t.tf_world_frame is not None
        if t.pose or (not use_tf and stamped):
            topic = t.pose or (stamped[0] if len(stamped) == 1 else None)
            if topic is None:
                raise self._missing("geometry_msgs/PoseStamped", "pose", stamped)
            if self.types.get(topic) != POSE_STAMPED:
                raise InputDataError("not a PoseStamped topic in the log", path=self.file, topic=topic,
                                     field="ingest.topics.pose", expected=f"one of {stamped}")
            self.pose_topics = {topic: POSE_STAMPED}
            link = PoseLink("world", "camera")
            return [link], {link.name: topic}, f"geometry_msgs/PoseStamped on {topic} (header.frame_id -> camera)"
        if "/tf" not in self.types:
            raise InputDataError("no camera pose in the log", path=self.file, field="ingest.topics.pose",
                                 expected="a geometry_msgs/PoseStamped topic or /tf (tf2_msgs/TFMessage)")
        camera = t.tf_camera_frame or self._first_frame_id(rgb)
        parent: dict[str, tuple[str, np.ndarray | None]] = {}
        tf_topics = ["/tf"] + (["/tf_static"] if "/tf_static" in self.types else [])
        start = self.summary.statistics.message_start_time if self.summary.statistics else 0
        if "/tf_static" in self.types:
            for i, (_, _, msg) in enumerate(self._messages(["/tf_static"])):
                for tr in self._decode(TF, msg.data, "/tf_static", i).transforms:
                    parent[tr.child_frame_id] = (tr.header.frame_id, self._tf_pose(tr, "/tf_static", i))
        for i, (_, _, msg) in enumerate(self._messages(["/tf"], ending_before=start + _TF_PREAMBLE_NS)):
            for tr in self._decode(TF, msg.data, "/tf", i).transforms:
                parent.setdefault(tr.child_frame_id, (tr.header.frame_id, None))
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
        self.pose_topics = {k: TF for k in tf_topics}
        names = " -> ".join([chain[0].parent] + [lk.child for lk in chain])
        where = {lk.name: ("/tf_static" if lk.static is not None else "/tf") for lk in chain}
        return chain, where, f"tf chain {names} (static links from /tf_static; dynamic links interpolated)"

    def _first_frame_id(self, topic: str) -> str:
        for _, _, msg in self._messages([topic]):
            parse = parse_image_cdr if self.types[topic] == IMAGE else parse_compressed_cdr
            return parse(msg.data)["frame_id"]
        raise InputDataError("colour topic has no messages", path=self.file, topic=topic, expected="images")

    def _tf_pose(self, tr, topic: str, index: int) -> np.ndarray:
        tt, q = tr.transform.translation, tr.transform.rotation
        return pose_from_tq_checked([tt.x, tt.y, tt.z, q.x, q.y, q.z, q.w], path=self.file, topic=topic, frame=index,
                                    field=f"transforms[{tr.header.frame_id}->{tr.child_frame_id}]")

    def _ground_truth(self) -> dict | None:
        from pipeline.scene_gt import GTScene

        try:
            atts = [a for a in self._reader.iter_attachments() if a.name == "ground_truth.json"]
        except Exception as err:
            raise _corrupt(self.file, err) from None
        if not atts:
            return None
        try:
            return GTScene.model_validate(json.loads(atts[0].data)).model_dump(mode="json")
        except Exception as err:
            raise InputDataError(f"ground_truth.json attachment is invalid: {err}", path=self.file,
                                 field="attachment ground_truth.json", expected="a GTScene JSON document") from None

    # ------------------------------------------------------------------ stream
    def samples(self) -> Iterator[Sample]:
        image_topics = {self.topics[s]: s for s in (RGB, DEPTH, INSTANCE) if s in self.topics}
        info_topic = self.topics["camera_info"]
        dynamic = {lk.name for lk in self.chain if lk.static is None}
        index: dict[str, int] = {}
        topics = list(image_topics) + [info_topic] + list(self.pose_topics)
        for _, channel, msg in self._messages(topics):
            topic = channel.topic
            i = index[topic] = index.get(topic, -1) + 1
            if topic in image_topics:
                yield self._image_sample(image_topics[topic], topic, msg, i)
            elif topic == info_topic:
                self._check_info(msg.data, i)
            elif self.pose_topics.get(topic) == POSE_STAMPED:
                m = self._decode(POSE_STAMPED, msg.data, topic, i)
                p, q = m.pose.position, m.pose.orientation
                T = pose_from_tq_checked([p.x, p.y, p.z, q.x, q.y, q.z, q.w], path=self.file, topic=topic, frame=i,
                                         field="pose")
                yield Sample(POSE, self._stamp(m.header.stamp, msg.log_time), i, T, key="world->camera", rigid=True)
            elif topic == "/tf":
                for tr in self._decode(TF, msg.data, topic, i).transforms:
                    name = f"{tr.header.frame_id}->{tr.child_frame_id}"
                    if name in dynamic:
                        yield Sample(POSE, self._stamp(tr.header.stamp, msg.log_time), i, self._tf_pose(tr, topic, i),
                                     key=name, rigid=True)

    @staticmethod
    def _stamp(stamp, log_time: int) -> int:
        ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
        return ns if ns else int(log_time)

    def _image_sample(self, stream: str, topic: str, msg, i: int) -> Sample:
        where = {"path": self.file, "topic": topic, "frame": i}
        try:
            if self.types[topic] == IMAGE:
                m = parse_image_cdr(msg.data)
            else:
                m = parse_compressed_cdr(msg.data)
        except (ValueError, IndexError, UnicodeDecodeError) as err:
            raise InputDataError(f"message is not a valid {self.types[topic]} ({err})", **where) from None
        stamp = m["stamp_ns"] or int(msg.log_time)
        if self.types[topic] == IMAGE:
            from pipeline.ros2 import RAW_ENCODINGS

            if m["encoding"] not in RAW_ENCODINGS:
                raise InputDataError(f"unknown image encoding {m['encoding']!r}", **where, field="encoding",
                                     expected=f"one of {sorted(RAW_ENCODINGS)}")
            intr = self.intrinsics
            if (m["width"], m["height"]) != (intr.width, intr.height):
                raise InputDataError(f"image is {m['width']}x{m['height']}", **where, field="width/height", expected=
                                     f"{intr.width}x{intr.height} as in CameraInfo {self.topics['camera_info']}")
            return Sample(stream, stamp, i, lambda: raw_image_to_array(m, where=where))
        return Sample(stream, stamp, i, lambda: compressed_image_to_array(m, where=where))

    def _check_info(self, data: bytes, i: int) -> None:
        topic = self.topics["camera_info"]
        info = self._decode(CAMERA_INFO, data, topic, i)
        K = np.asarray(info.k, dtype=np.float64).reshape(3, 3)
        if (info.width, info.height) != (self.intrinsics.width, self.intrinsics.height) or not np.allclose(
                K, self.intrinsics.K, rtol=0, atol=1e-9):
            raise InputDataError(f"CameraInfo changed to {info.width}x{info.height}, K {K.tolist()}", path=self.file,
                                 topic=topic, field="k/width/height", frame=i,
                                 expected=f"constant intrinsics as in message 0 ({self.intrinsics.to_dict()})")
