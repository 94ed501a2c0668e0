"""Raw-data readers (one file per format) behind :class:`pipeline.readers.base.Reader`, the shared matcher, and
:mod:`~pipeline.readers.ingest` (the ingest stage's work: source -> ``frames.zarr``)."""

from pipeline.readers import mcap, navchat, replica, rosbag, scannet, sevenscenes, tum  # noqa: F401  (register the readers)
from pipeline.readers.base import READERS, Reader, Sample, SourceInfo, detect_format, open_reader
from pipeline.readers.matcher import FrameMatcher

__all__ = ["READERS", "Reader", "Sample", "SourceInfo", "FrameMatcher", "detect_format", "open_reader"]
