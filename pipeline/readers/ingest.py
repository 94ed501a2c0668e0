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
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

from pipeline.config import IngestParams
from pipeline.stageconfig import digest_value
from pipeline.errors import InputDataError
from pipeline.frames import ARTIFACT, FORMAT_VERSION, FrameBlock, FrameStoreWriter
from pipeline import plugins
from pipeline.readers import FrameMatcher, open_reader
from pipeline.readers.matcher import index_ranges
from pipeline.readers.world_up import WorldUp
from pipeline.store import ArrayDigests, artifact_attrs, remove


def ingest(source: Path | Sequence[Path], out_path: Path, params: IngestParams, fmt: str = "auto", *,
           params_digest: str, label: Callable[[Path], str] = Path.as_posix, log: Callable[[str], None] = print,
           progress=None, digests: ArrayDigests | None = None) -> dict:
    """Read ``source`` (one log / folder, or several of one scene, read in order) and write ``out_path`` (a new
    frames.zarr). Frame indices continue from one log to the next; stamps stay as recorded; every log must
    carry the first one's camera (intrinsics, instance images, ground truth, world convention), and it takes
    the first one's world rotation. Returns the matching summary (with several logs: counts summed over the
    logs, one summary per log under ``sources``). ``label`` names a log in messages and attrs; ``digests`` keeps
    the arrays' content digests as they are written (:class:`pipeline.frames.FrameStoreWriter`)."""
    paths = [Path(source)] if isinstance(source, (str, Path)) else [Path(p) for p in source]
    if not paths:
        raise InputDataError("no raw log or dataset folder to read", field="scenes.<scene>.sources",
                             expected="at least one path")
    labels = [label(p) for p in paths]
    writer: FrameStoreWriter | None = None
    first: _Log | None = None
    world: WorldUp | None = None
    valid_fraction: list[np.ndarray] = []
    summaries, provenance = [], []
    try:
        for path, name in zip(paths, labels, strict=True):
            one = _Log(path, name, params, fmt, log)
            if first is None:
                first, world = one, WorldUp(params, one.reader.world_up, one.info.intrinsics,
                                            levelled=one.reader.world_up_levelled, source=name, log=log)
                if one.info.ground_truth is not None and not world.identity:
                    raise InputDataError(f"ingest.world_up {params.world_up!r} would rotate a log that carries ground "
                                         "truth", path=name, field="ingest.world_up",
                                         expected="'dataset' or '+z' for simulated logs")
                writer = FrameStoreWriter(out_path, one.info.intrinsics, attrs=one.attrs(params, params_digest),
                                          block_frames=params.block_frames, with_instance=one.info.has_instance,
                                          compression_level=params.compression_level, codec=params.codec,
                                          digests=digests)
                blocks = world.apply(one.blocks())
            else:
                one.check_same_camera(first)
                blocks = _after(world.rotated(one.blocks()), writer.n)  # the scene's one world: the first log's
            start, fractions = writer.n, []
            with _BackgroundAppender(writer) as appender:
                for block in (progress(blocks, description="frames") if progress else blocks):
                    fractions.append((block.depth_mm > 0).mean(axis=(1, 2)))
                    appender.append(block)
            summaries.append(one.checked_summary(fractions, params, start))
            valid_fraction += fractions
            provenance.append({**one.provenance(params), "frames": [start, start + summaries[-1]["matched_frames"]]})
        summary = summaries[0] if len(summaries) == 1 else _merged(summaries, labels)
        frac = np.concatenate(valid_fraction)
        empty = np.flatnonzero(frac == 0).tolist()
        summary["depth_valid_fraction"] = {"min": float(frac.min()), "mean": float(frac.mean())}
        summary["frames_without_valid_depth"] = {"count": len(empty), "ranges": index_ranges(empty)}
        if len(provenance) > 1:  # each log's own record and frame range [start, stop)
            writer.group.attrs["provenance"] = {"sources": [{k: v for k, v in p.items() if k != "depth_range_applied"}
                                                            for p in provenance],
                                                "depth_range_applied": provenance[0]["depth_range_applied"]}
        writer.close(matching=summary, world_up=world.record())
    except BaseException:
        remove(out_path)
        raise
    log(_describe(summary))
    return summary


class _Log:
    """One raw log of a scene: its reader, opened, and its time matcher."""

    def __init__(self, path: Path, label: str, params: IngestParams, fmt: str, log: Callable[[str], None]):
        self.label = label
        self.reader = open_reader(path, params, fmt)
        with plugins.running(type(self.reader), "open"):
            self.opened = self.reader.open()
        self.info = self.opened.info
        log(f"reading {label} as {self.reader.name}: {self.info.intrinsics.width}x{self.info.intrinsics.height}, "
            f"pose from {' -> '.join(lk.name for lk in self.info.pose_chain)}")
        self.matcher = FrameMatcher(self.info, params, label)

    def blocks(self) -> Iterator[FrameBlock]:
        return self.matcher.blocks(plugins.iterate(type(self.reader), "samples",
                                                   self.reader.samples(self.opened)))

    def provenance(self, params: IngestParams) -> dict:
        return {"source": self.label, "format": self.reader.name, "reader": type(self.reader).__name__,
                **self.info.provenance,
                "depth_range_applied": f"depth outside [{params.depth_min_m}, {params.depth_max_m}] m set to 0"}

    def attrs(self, params: IngestParams, params_digest: str) -> dict:
        attrs = artifact_attrs(ARTIFACT, FORMAT_VERSION, "ingest", params_digest, depth_unit="mm",
                               depth_range_m=[params.depth_min_m, params.depth_max_m],
                               provenance=self.provenance(params))
        if self.info.ground_truth is not None:
            attrs["ground_truth"] = self.info.ground_truth
        return attrs

    def check_same_camera(self, first: "_Log") -> None:
        """A later log of the scene must be recorded like the first one (one store, one world)."""
        a, b = first.info.intrinsics, self.info.intrinsics
        same_k = (a.width, a.height) == (b.width, b.height) and np.allclose(
            [a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=1e-6, atol=1e-6)
        has = {True: "instance images", False: "no instance images"}
        checks = [
            ("intrinsics", same_k, _camera(b), _camera(a)),
            ("instance", self.info.has_instance == first.info.has_instance, has[self.info.has_instance],
             has[first.info.has_instance]),
            ("ground truth", self.info.ground_truth == first.info.ground_truth,
             "ground truth of another scene" if self.info.ground_truth else "no ground truth",
             "its own ground truth" if first.info.ground_truth else "none"),
            ("world convention", (self.reader.world_up, self.reader.world_up_levelled)
             == (first.reader.world_up, first.reader.world_up_levelled),
             f"a world with {self.reader.world_up} up", f"{first.reader.world_up} up"),
        ]
        for what, same, got, expected in checks:
            if not same:
                raise InputDataError(f"this log has {got}; the scene's first log {first.label} has {expected}",
                                     path=self.label, field=what,
                                     expected="every log of a scene recorded with the first log's camera and world")

    def checked_summary(self, fractions: list[np.ndarray], params: IngestParams, start: int) -> dict:
        """The matcher's summary; no matched frame, or no valid depth in any, is an error naming this log."""
        summary = self.matcher.summary()
        frac = np.concatenate(fractions) if fractions else np.zeros(0)
        if summary["matched_frames"] == 0:
            raise InputDataError(f"no frame could be matched: {_describe(summary)}", path=self.label,
                                 expected="colour frames with depth within max_rgb_depth_dt_s and pose coverage")
        if not frac.any():
            raise InputDataError(f"all {len(frac)} matched frames have no valid depth in "
                                 f"[{params.depth_min_m}, {params.depth_max_m}] m", path=self.label,
                                 topic=self.info.where.get("depth"), field="depth",
                                 expected="depth in millimetres (16UC1) or metres (32FC1) inside "
                                          "ingest.depth_min_m..depth_max_m")
        return summary if start == 0 else {**summary, "first_frame": start}


def _camera(k) -> str:
    return f"{k.width}x{k.height} fx {k.fx:.6g} fy {k.fy:.6g} cx {k.cx:.6g} cy {k.cy:.6g}"


def _after(blocks: Iterable[FrameBlock], offset: int) -> Iterator[FrameBlock]:
    """A later log's blocks, indexed after the ``offset`` frames already written."""
    for b in blocks:
        b.start += offset
        yield b


def _merged(summaries: list[dict], labels: list[str]) -> dict:
    """Several logs' matching summaries as one: message and unmatched counts summed, each log's own kept."""
    def add(dicts):
        out: dict = {}
        for d in dicts:
            for k, v in d.items():
                out[k] = add([out.get(k, {}), v]) if isinstance(v, dict) else out.get(k, 0) + v
        return out

    return {"messages": dict(sorted(add(s["messages"] for s in summaries).items())),
            "matched_frames": sum(s["matched_frames"] for s in summaries),
            "unmatched": add(s["unmatched"] for s in summaries),
            "sources": [{"source": label, **s} for label, s in zip(labels, summaries)]}


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
