"""Ingest: a raw log or dataset folder -> ``frames.zarr`` (the work of the ``ingest`` stage).

Reads the source with the reader of its format ('auto' detects it; :mod:`pipeline.readers.base`),
matches colour, depth and pose by time (:mod:`pipeline.readers.matcher`), and streams frame blocks
into :class:`pipeline.frames.FrameStoreWriter`. The matching report (counts per stream, matched and
unmatched frames by reason, tolerances) is logged, stored in the store's attrs ``matching`` and
returned as the summary. Depth outside ``[depth_min_m, depth_max_m]`` is stored as 0. Poses are
turned into the z-up world (:mod:`pipeline.readers.world_up`, ``ingest.world_up``; attrs ``world_up``).
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Callable

import numpy as np

from pipeline.config import IngestParams, digest_value
from pipeline.errors import InputDataError
from pipeline.frames import ARTIFACT, FORMAT_VERSION, FrameStoreWriter
from pipeline.readers import FrameMatcher, open_reader
from pipeline.readers.matcher import index_ranges
from pipeline.readers.world_up import WorldUp
from pipeline.store import artifact_attrs, remove


def ingest(source: Path, out_path: Path, params: IngestParams, fmt: str = "auto", *, params_digest: str,
           source_label: str | None = None, log: Callable[[str], None] = print, progress=None) -> dict:
    """Read ``source`` and write ``out_path`` (a new frames.zarr). Returns the matching summary."""
    source = Path(source)
    reader = open_reader(source, params, fmt)
    info = reader.open()
    label = source_label or source.as_posix()
    log(f"reading {label} as {reader.name}: {info.intrinsics.width}x{info.intrinsics.height}, "
        f"pose from {' -> '.join(lk.name for lk in info.pose_chain)}")
    matcher = FrameMatcher(info, params, label)
    world = WorldUp(params, reader.world_up, info.intrinsics, levelled=reader.world_up_levelled, source=label,
                    log=log)
    if info.ground_truth is not None and not world.identity:
        raise InputDataError(f"ingest.world_up {params.world_up!r} would rotate a log that carries ground truth",
                             path=label, field="ingest.world_up", expected="'dataset' or '+z' for simulated logs")
    attrs = artifact_attrs(
        ARTIFACT, FORMAT_VERSION, "ingest", params_digest,
        depth_unit="mm", depth_range_m=[params.depth_min_m, params.depth_max_m],
        provenance={"source": label, "format": reader.name, "reader": type(reader).__name__, **info.provenance,
                    "depth_range_applied": f"depth outside [{params.depth_min_m}, {params.depth_max_m}] m set to 0"},
    )
    if info.ground_truth is not None:
        attrs["ground_truth"] = info.ground_truth
    writer = FrameStoreWriter(out_path, info.intrinsics, attrs=attrs, block_frames=params.block_frames,
                              with_instance=info.has_instance, compression_level=params.compression_level,
                              codec=params.codec)
    valid_fraction: list[np.ndarray] = []
    try:
        blocks = world.apply(matcher.blocks(reader.samples()))
        with _BackgroundAppender(writer) as appender:
            for block in (progress(blocks, description="frames") if progress else blocks):
                valid_fraction.append((block.depth_mm > 0).mean(axis=(1, 2)))
                appender.append(block)
        summary = matcher.summary()
        frac = np.concatenate(valid_fraction) if valid_fraction else np.zeros(0)
        empty = np.flatnonzero(frac == 0).tolist()
        summary["depth_valid_fraction"] = {"min": float(frac.min()) if frac.size else 0.0,
                                           "mean": float(frac.mean()) if frac.size else 0.0}
        summary["frames_without_valid_depth"] = {"count": len(empty), "ranges": index_ranges(empty)}
        if summary["matched_frames"] == 0:
            raise InputDataError(f"no frame could be matched: {_describe(summary)}", path=label,
                                 expected="colour frames with depth within max_rgb_depth_dt_s and pose coverage")
        if len(empty) == len(frac):
            raise InputDataError(f"all {len(frac)} matched frames have no valid depth in "
                                 f"[{params.depth_min_m}, {params.depth_max_m}] m", path=label,
                                 topic=info.where.get("depth"), field="depth",
                                 expected="depth in millimetres (16UC1) or metres (32FC1) inside "
                                          "ingest.depth_min_m..depth_max_m")
        writer.close(matching=summary, world_up=world.record())
    except BaseException:
        remove(out_path)
        raise
    log(_describe(summary))
    return summary


class _BackgroundAppender:
    """Compress and write blocks in a second thread while the next ones are read (zstd, blosc and
    numpy release the GIL). At most ``depth`` blocks wait, so memory stays bounded; a writer error
    is re-raised in the caller."""

    def __init__(self, writer: FrameStoreWriter, depth: int = 1):
        self.writer = writer
        self.queue: queue.Queue = queue.Queue(maxsize=depth)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._work, name="frames-writer", daemon=True)

    def _work(self) -> None:
        while (block := self.queue.get()) is not None:
            if self.error is None:
                try:
                    self.writer.append(block)
                except BaseException as err:  # noqa: BLE001 - handed to the reading thread, re-raised there
                    self.error = err

    def append(self, block) -> None:
        if self.error is not None:
            raise self.error
        self.queue.put(block)

    def __enter__(self) -> "_BackgroundAppender":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.queue.put(None)
        self.thread.join()
        if self.error is not None and exc[0] is None:
            raise self.error


def _describe(summary: dict) -> str:
    msgs = ", ".join(f"{k} {v}" for k, v in summary["messages"].items())
    parts = [f"matched {summary['matched_frames']} frames ({msgs})"]
    for stream, reasons in summary["unmatched"].items():
        if reasons:
            parts.append(f"unmatched {stream}: " + ", ".join(f"{n} {r}" for r, n in reasons.items()))
    empty = summary.get("frames_without_valid_depth", {}).get("count")
    if empty:
        parts.append(f"{empty} frames without valid depth")
    return "; ".join(parts)


def ingest_path(path, out_path, params: IngestParams, fmt: str = "auto", *, log=print) -> dict:
    """``zipon ingest PATH``: ingest a log/folder outside the runner (writes ``out_path`` directly)."""
    return ingest(Path(path), Path(out_path), params, fmt, params_digest=digest_value(params.model_dump(mode="json")),
                  log=log)
