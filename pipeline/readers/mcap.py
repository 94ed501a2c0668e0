"""ROS 2 MCAP logs through the ``mcap`` library (``mcap`` + ``mcap_ros2``; no ROS installation needed).

The fast path for ``.mcap``: chunk-indexed reads, images parsed from CDR with numpy (the layout is
fixed) and decoded only when matched. Topic detection, tf, depth registration and streaming are
:class:`pipeline.readers.roslog.RosLogReader`'s (shared with the ``rosbags`` reader); this file is the
container: :class:`McapSource`. A ``ground_truth.json`` attachment (:class:`pipeline.scene_gt.GTScene`,
written by zipon's simulator) is carried into the frame store; MCAP metadata records go into provenance.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

from pipeline.errors import InputDataError
from pipeline.readers.roslog import MessageSource, RosLogReader
from pipeline.ros2 import IMAGE, parse_compressed_cdr, parse_image_cdr


def _corrupt(path, err: Exception) -> InputDataError:
    return InputDataError(f"not a readable MCAP log (truncated or corrupt: {type(err).__name__}: {err})", path=path,
                          expected="a complete MCAP file with a summary section (repair with `mcap recover`)")


class McapSource(MessageSource):
    """An indexed MCAP file read with ``mcap``'s chunk index; messages are ``mcap`` Message records."""

    def __init__(self, file: Path):
        from mcap.reader import make_reader

        self.file = file
        try:
            self._stream = open(file, "rb")
            self._reader = make_reader(self._stream, validate_crcs=True)
            summary = self._reader.get_summary()
        except Exception as err:  # noqa: BLE001 - mcap raises McapError, struct.error, EndOfFile, ValueError...
            raise _corrupt(file, err) from None
        if summary is None or not summary.chunk_indexes and summary.statistics and summary.statistics.message_count:
            raise InputDataError("log has no summary/chunk index", path=file,
                                 expected="an indexed MCAP file (repair with `mcap recover`)")
        self.summary = summary
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        self.types, self.counts = {}, {}
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
            self.types[ch.topic] = schema.name if schema else "(no schema)"
            self.counts[ch.topic] = self.counts.get(ch.topic, 0) + int(counts.get(ch.id, 0))
        self.start_ns = int(summary.statistics.message_start_time) if summary.statistics else 0
        self._decoders: dict[str, Any] = {}

    def messages(self, topics: list[str], stop_ns: int | None = None) -> Iterator[tuple[str, int, Any]]:
        kw = {} if stop_ns is None else {"ending_before": stop_ns}
        try:
            for _, channel, msg in self._reader.iter_messages(topics=topics, **kw):
                yield channel.topic, int(msg.log_time), msg
        except InputDataError:
            raise
        except Exception as err:  # noqa: BLE001 - any failure of the mcap reader means a corrupt file
            raise _corrupt(self.file, err) from None

    def decode(self, topic: str, raw, index: int):
        from mcap_ros2._dynamic import generate_dynamic

        name = self.types[topic]
        if name not in self._decoders:
            schema = next(s for s in self.summary.schemas.values() if s.name == name)
            self._decoders[name] = generate_dynamic(schema.name, schema.data.decode())[schema.name]
        return self._decoders[name](raw.data)

    def image(self, topic: str, raw, index: int) -> dict:
        return (parse_image_cdr if self.types[topic] == IMAGE else parse_compressed_cdr)(raw.data)

    def ground_truth_json(self) -> bytes | None:
        try:
            atts = [a for a in self._reader.iter_attachments() if a.name == "ground_truth.json"]
        except Exception as err:  # noqa: BLE001 - any failure of the mcap reader means a corrupt file
            raise _corrupt(self.file, err) from None
        return atts[0].data if atts else None

    def metadata(self) -> dict:
        try:
            meta = {m.name: dict(m.metadata) for m in self._reader.iter_metadata()}
        except Exception as err:  # noqa: BLE001 - any failure of the mcap reader means a corrupt file
            raise _corrupt(self.file, err) from None
        s = self.summary.statistics
        return {"mcap_metadata": meta,
                "log_time_range_ns": [int(s.message_start_time), int(s.message_end_time)] if s else None}

    def close(self) -> None:
        self._stream.close()


class McapReader(RosLogReader):
    """A ``.mcap`` file, or a rosbag2 folder holding exactly one (see the module doc)."""

    name = "mcap"
    layout = "a ROS 2 .mcap file (or rosbag2 folder holding one)"

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

    def _source(self) -> MessageSource:
        return McapSource(self._log_file(self.path) or self.path)
