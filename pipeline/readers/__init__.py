"""Raw-data readers (one file per format) behind :class:`pipeline.readers.base.Reader`, the shared matcher, and
:mod:`~pipeline.readers.ingest` (the ingest stage's work: source -> ``frames.zarr``). A reader module is imported
when its format is used (:func:`~pipeline.readers.base.reader_class`)."""

from pipeline.readers.base import (READERS, Opened, Reader, Sample, SourceInfo, all_readers, detect_format, open_reader,
                                   reader_class)
from pipeline.readers.matcher import FrameMatcher

__all__ = ["READERS", "Opened", "Reader", "Sample", "SourceInfo", "FrameMatcher", "all_readers", "detect_format",
           "open_reader", "reader_class"]
