"""ROS 1 ``.bag`` and ROS 2 bags (``.db3`` SQLite, ``.mcap``, or a rosbag2 folder) through ``rosbags``.

``rosbags`` (pure Python) reads all three containers with the message definitions stored in the bag,
so no ROS installation is needed (ROS 2 bags recorded before Iron store none: their standard messages
are read with rosbags' Humble type store, as provenance records). Everything but the container -- topic detection, tf,
depth registration, time matching -- is :class:`pipeline.readers.roslog.RosLogReader`'s, shared with
the MCAP reader. ROS 2 (CDR) images are parsed with the same numpy CDR parser as MCAP; ROS 1 images
through ``rosbags``' deserialiser (its arrays are numpy views). ROS 1 names its CameraInfo fields
``K``/``D``; both spellings are read.

Detection: a ``.bag`` file (``#ROSBAG V2.0``), a ``.db3`` file (SQLite), or a folder with
``metadata.yaml`` and ``.db3`` files. ``.mcap`` files and rosbag2 folders holding one are detected as
``mcap`` (the faster reader, see ``benchmarks/bench_ingest.py``); ``--format rosbag`` reads them with
``rosbags`` too.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any, Iterator

from pipeline.errors import InputDataError
from pipeline.readers.roslog import MessageSource, RosLogReader
from pipeline.ros2 import IMAGE, parse_compressed_cdr, parse_image_cdr
from pipeline.userfiles import load_user_file

ROS1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3\x00"
EXPECTED = "a ROS 1 .bag, a ROS 2 .db3/.mcap bag or a rosbag2 folder (metadata.yaml), complete and readable"


def _bad(path, err: Exception) -> InputDataError:
    return InputDataError(f"not a readable ROS bag ({type(err).__name__}: {err})", path=path, expected=EXPECTED)


def _magic(path: Path, n: int) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


class RosbagsSource(MessageSource):
    """A bag opened with ``rosbags.highlevel.AnyReader``; messages are ``(connection, raw bytes)``."""

    def __init__(self, path: Path):
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        self.file = path
        meta = (path if path.is_dir() else path.parent) / "metadata.yaml"
        if meta.is_file():  # read bounded before rosbags reads it unbounded (aliases, size)
            load_user_file(meta, fmt="yaml")
        try:
            # ROS 2 bags before Iron store no message definitions: the standard types are read with Humble's
            self._reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self._reader.open()
        except Exception as err:  # noqa: BLE001 - rosbags raises ReaderError, AnyReaderError, sqlite/yaml errors...
            raise _bad(path, err) from None
        self.types, self.counts = {}, defaultdict(int)
        self._conns: dict[str, list] = defaultdict(list)
        for c in self._reader.connections:
            self.types.setdefault(c.topic, c.msgtype)
            self.counts[c.topic] += int(c.msgcount)
            self._conns[c.topic].append(c)
        self.start_ns = int(self._reader.start_time) if self._reader.connections else 0

    def messages(self, topics: list[str], stop_ns: int | None = None) -> Iterator[tuple[str, int, Any]]:
        conns = [c for t in topics for c in self._conns.get(t, [])]
        if not conns:
            return
        try:
            for c, log_time, data in self._reader.messages(connections=conns, stop=stop_ns):
                yield c.topic, int(log_time), (c, data)
        except InputDataError:
            raise
        except Exception as err:  # noqa: BLE001 - any failure of the rosbags reader means a corrupt bag
            raise _bad(self.file, err) from None

    def decode(self, topic: str, raw, index: int):
        c, data = raw
        return self._reader.deserialize(data, c.msgtype)

    def image(self, topic: str, raw, index: int) -> dict:
        c, data = raw
        raw_image = self.types[topic] == IMAGE
        if getattr(c.ext, "serialization_format", None) == "cdr":
            return (parse_image_cdr if raw_image else parse_compressed_cdr)(data)
        m = self._reader.deserialize(data, c.msgtype)
        out = {"stamp_ns": int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec),
               "frame_id": m.header.frame_id, "data": m.data}
        if raw_image:
            out.update(height=int(m.height), width=int(m.width), encoding=m.encoding,
                       is_bigendian=int(m.is_bigendian), step=int(m.step))
        else:
            out["format"] = m.format
        return out

    def metadata(self) -> dict:
        r = self._reader
        own = all(c.msgdef.format.name != "NONE" for c in r.connections)
        return {"bag": {"container": "ROS 1 bag" if not r.is2 else "ROS 2 bag", "reader": "rosbags",
                        "message_definitions": "the bag's own" if own else "rosbags' ROS 2 Humble type store",
                        "log_time_range_ns": [int(r.start_time), int(r.end_time)] if r.connections else None}}

    def close(self) -> None:
        self._reader.close()


class RosbagReader(RosLogReader):
    """See the module doc."""

    name = "rosbag"
    layout = "a ROS 1 .bag or a ROS 2 .db3 (or rosbag2 folder holding one)"

    @classmethod
    def detect(cls, path: Path) -> bool:
        if path.is_file():
            head = _magic(path, 16)
            return path.suffix in (".bag", ".db3") or head.startswith(ROS1_MAGIC) or head == SQLITE_MAGIC
        return path.is_dir() and (path / "metadata.yaml").is_file() and next(path.glob("*.db3"), None) is not None

    def _source(self) -> MessageSource:
        if not self.path.exists():
            raise InputDataError("bag not found", path=self.path, expected=EXPECTED)
        return RosbagsSource(self.path)
