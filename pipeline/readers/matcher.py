"""Streaming timestamp matcher shared by every reader: samples in, :class:`FrameBlock` s out.

Colour frames define the output frames. For each colour frame (in time order):

- depth: the nearest unused depth frame within ``max_rgb_depth_dt_s`` (ties: the earlier one);
  depth frames older than the chosen one can no longer be nearest to a later colour frame and are
  reported unmatched;
- instance (when the source has it): the same rule, same tolerance;
- pose: each dynamic link of the pose chain is taken at the colour stamp: exactly when a sample
  has that stamp, else interpolated (linear translation, slerp) between the bracketing samples
  if they are at most ``max_pose_gap_s`` apart, else the first/last sample if the stamp lies within
  ``max_pose_extrapolation_s`` outside the link's range; static links are constant. The links
  compose left to right into ``T_world_camera``.

A colour frame is decided once every stream it needs has advanced past ``stamp + tolerance`` (or
ended), or once any stream is ``max_stream_lag_s`` ahead, so memory holds only that window (images
stay undecoded until matched) whatever the log length. Every message is accounted for: matched, or
counted under a reason in the summary, with the message indices of unmatched colour frames as ranges.
"""

from __future__ import annotations

import bisect
from collections import Counter, deque
from typing import Iterable, Iterator

import numpy as np

from pipeline.config import IngestParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameBlock
from pipeline.geometry import check_rigid, interpolate_poses
from pipeline.readers.base import DEPTH, IMAGE_STREAMS, INSTANCE, POSE, RGB, PoseLink, Sample, SourceInfo

NS = 1_000_000_000


class _LinkTrack:
    """Samples of one dynamic pose link, trimmed as colour frames are decided."""

    def __init__(self, link: PoseLink):
        self.link = link
        self.stamps: list[int] = []
        self.poses: list[np.ndarray] = []
        self.ended = False

    def ready(self, t: int) -> bool:
        return self.ended or (bool(self.stamps) and self.stamps[-1] >= t)

    def query(self, t: int, gap_ns: int, extrap_ns: int) -> tuple[np.ndarray | None, str]:
        """Pose at ``t`` and how it was obtained ('exact', 'interpolated', 'extrapolated') or why not."""
        s = self.stamps
        i = bisect.bisect_left(s, t)
        if i < len(s) and s[i] == t:
            return self.poses[i], "exact"
        if 0 < i < len(s):
            if s[i] - s[i - 1] > gap_ns:
                return None, "pose_gap_exceeds_max"
            pair = np.stack([self.poses[i - 1], self.poses[i]])
            return interpolate_poses(np.array([s[i - 1], s[i]]), pair, np.array([t]))[0], "interpolated"
        if i == 0 and s and s[0] - t <= extrap_ns:
            return self.poses[0], "extrapolated"
        if i == len(s) and s and t - s[-1] <= extrap_ns:
            return self.poses[-1], "extrapolated"
        return None, "outside_pose_range"

    def trim(self, t: int) -> None:
        """Forget samples no later colour stamp (>= t) can need (keep the one bracketing t)."""
        i = bisect.bisect_right(self.stamps, t) - 1
        if i > 0:
            del self.stamps[:i], self.poses[:i]


def index_ranges(indices: list[int]) -> list[list[int]]:
    """Sorted ints -> ``[[first, last], ...]`` runs (compact, complete)."""
    out: list[list[int]] = []
    for i in indices:
        if out and i == out[-1][1] + 1:
            out[-1][1] = i
        else:
            out.append([i, i])
    return out


class FrameMatcher:
    """Match one source's samples into frames; see the module doc. Use :meth:`blocks`."""

    def __init__(self, info: SourceInfo, params: IngestParams, source: str):
        self.info, self.params, self.source = info, params, source
        self.tol_ns = int(round(params.max_rgb_depth_dt_s * NS))
        self.gap_ns = int(round(params.max_pose_gap_s * NS))
        self.extrap_ns = int(round(params.max_pose_extrapolation_s * NS))
        self.lag_ns = int(round(params.max_stream_lag_s * NS))
        self.streams = [RGB, DEPTH] + ([INSTANCE] if info.has_instance else [])
        self.pending: dict[str, deque[Sample]] = {s: deque() for s in self.streams}
        self.last_stamp: dict[str, int] = {}
        self.last_index: dict[str, int] = {}
        self.ended: set[str] = set()
        self.tracks = {lk.name: _LinkTrack(lk) for lk in info.pose_chain if lk.static is None}
        self.counts: Counter = Counter()
        self.unmatched: dict[str, Counter] = {s: Counter() for s in self.streams}
        self.unmatched_rgb_index: dict[str, list[int]] = {}
        self.pose_how: Counter = Counter()
        self.max_dt_ns = {DEPTH: 0, INSTANCE: 0}
        self.frontier = None  # latest stamp seen on any stream
        self.n_out = 0

    # ------------------------------------------------------------------ input
    def _where(self, stream: str) -> dict:
        return {"path": self.source, "topic": self.info.where.get(stream)}

    def _accept(self, s: Sample) -> None:
        key = s.key if s.stream == POSE else s.stream
        prev = self.last_stamp.get(key)
        if prev is not None and s.stamp_ns <= prev:
            what = "duplicate" if s.stamp_ns == prev else "unsorted"
            raise InputDataError(
                f"{what} stamp {s.stamp_ns} ns after {prev} ns (message {self.last_index[key]})",
                **self._where(key), field="header.stamp", frame=s.index, expected="strictly increasing stamps")
        self.last_stamp[key], self.last_index[key] = s.stamp_ns, s.index
        self.counts[key] += 1
        self.frontier = s.stamp_ns if self.frontier is None else max(self.frontier, s.stamp_ns)
        if s.stream == POSE:
            track = self.tracks.get(s.key)
            if track is None:
                return
            T = np.asarray(s.payload, dtype=np.float64)
            if not s.rigid:  # quaternion-built poses are rigid by construction (readers check the quaternion)
                check_rigid(T, path=self.source, topic=self.info.where.get(s.key), first_frame=s.index)
            track.stamps.append(s.stamp_ns)
            track.poses.append(T)
        elif s.stream in self.pending:
            self.pending[s.stream].append(s)

    # ------------------------------------------------------------------ decisions
    def _ready(self, t: int, final: bool) -> bool:
        if final or (self.frontier is not None and self.frontier - t > self.lag_ns):
            return True
        for st in self.streams[1:]:
            if st not in self.ended and self.last_stamp.get(st, -1) < t + self.tol_ns:
                return False
        return all(tr.ready(t) for tr in self.tracks.values())

    def _take_nearest(self, stream: str, t: int) -> Sample | None:
        q = self.pending[stream]
        while q and q[0].stamp_ns < t - self.tol_ns:
            q.popleft()
            self.unmatched[stream]["no_rgb_within_tolerance"] += 1
        best = None
        for j, cand in enumerate(q):
            if cand.stamp_ns > t + self.tol_ns:
                break
            if best is None or abs(cand.stamp_ns - t) < abs(q[best].stamp_ns - t):
                best = j
        if best is None:
            return None
        for _ in range(best):
            q.popleft()
            self.unmatched[stream]["closer_frame_matched"] += 1
        return q.popleft()

    def _pose(self, t: int) -> tuple[np.ndarray | None, str]:
        T = np.eye(4)
        how = "exact"
        for link in self.info.pose_chain:
            if link.static is not None:
                T = T @ link.static
                continue
            P, h = self.tracks[link.name].query(t, self.gap_ns, self.extrap_ns)
            if P is None:
                return None, h
            T = T @ P
            if h != "exact":
                how = h
        return T, how

    def _decide(self, final: bool) -> Iterator[tuple[Sample, Sample, Sample | None, np.ndarray]]:
        rgbq = self.pending[RGB]
        while rgbq and self._ready(rgbq[0].stamp_ns, final):
            c = rgbq.popleft()
            t = c.stamp_ns
            d = self._take_nearest(DEPTH, t)
            inst = self._take_nearest(INSTANCE, t) if INSTANCE in self.pending else None
            T, how = self._pose(t)
            reason = ("no_depth_within_tolerance" if d is None else
                      "no_instance_within_tolerance" if (INSTANCE in self.pending and inst is None) else
                      None if T is not None else f"no_pose_coverage:{how}")
            for tr in self.tracks.values():
                tr.trim(t)
            if reason is not None:
                self.unmatched[RGB][reason] += 1
                self.unmatched_rgb_index.setdefault(reason, []).append(c.index)
                for other in (d, inst):
                    if other is not None:
                        self.unmatched[other.stream]["rgb_frame_unmatched"] += 1
                continue
            self.pose_how[how] += 1
            self.max_dt_ns[DEPTH] = max(self.max_dt_ns[DEPTH], abs(d.stamp_ns - t))
            if inst is not None:
                self.max_dt_ns[INSTANCE] = max(self.max_dt_ns[INSTANCE], abs(inst.stamp_ns - t))
            yield c, d, inst, T

    # ------------------------------------------------------------------ output
    def _image_where(self, s: Sample) -> dict:
        return {"path": s.origin} if s.origin is not None else self._where(s.stream)

    def _check_image(self, s: Sample, arr: np.ndarray, dtypes: tuple, channels: int | None) -> None:
        intr = self.info.intrinsics
        shape = (intr.height, intr.width) + ((channels,) if channels else ())
        if arr.shape != shape or arr.dtype not in dtypes:
            raise InputDataError(
                f"{s.stream} image is {arr.dtype}{tuple(arr.shape)}", **self._image_where(s), frame=s.index,
                expected=f"{' or '.join(str(np.dtype(x)) for x in dtypes)}{shape} "
                         f"({intr.width}x{intr.height} as in the camera intrinsics)")

    def _check_pair(self, c: Sample, rgb: np.ndarray, other: Sample, arr: np.ndarray) -> None:
        """Colour and a matched depth/instance image of different sizes: the error names both images."""
        if rgb.shape[:2] == arr.shape[:2]:
            return

        def name(s: Sample) -> str:
            return str(s.origin) if s.origin is not None else f"{self.info.where.get(s.stream)} message {s.index}"

        (hc, wc), (ho, wo) = rgb.shape[:2], arr.shape[:2]
        raise InputDataError(f"{other.stream} image {name(other)} is {wo}x{ho} but its colour image {name(c)} is "
                             f"{wc}x{hc}", path=self.source, frame=c.index,
                             expected="colour and depth (and instance) images of one size per frame")

    def depth_to_mm(self, arr: np.ndarray) -> np.ndarray:
        """uint16 mm or float metres -> uint16 mm with values outside [depth_min_m, depth_max_m] set to 0."""
        p = self.params
        if arr.dtype == np.uint16:
            mm = arr
        else:
            m = np.where(np.isfinite(arr), arr, 0.0)
            mm = np.clip(np.round(m * 1000.0), 0, 65535).astype(np.uint16)
        lo, hi = int(np.ceil(p.depth_min_m * 1000.0)), int(np.floor(p.depth_max_m * 1000.0))
        return np.where((mm >= lo) & (mm <= hi), mm, 0).astype(np.uint16)

    def _new_block(self) -> FrameBlock:
        b, h, w = self.params.block_frames, self.info.intrinsics.height, self.info.intrinsics.width
        return FrameBlock(rgb=np.empty((b, h, w, 3), np.uint8), depth_mm=np.empty((b, h, w), np.uint16),
                          T_world_camera=np.empty((b, 4, 4)), stamp_ns=np.empty(b, np.int64),
                          instance=np.empty((b, h, w), np.uint16) if self.info.has_instance else None)

    def blocks(self, samples: Iterable[Sample]) -> Iterator[FrameBlock]:
        """Consume ``samples`` (time-ordered); yield blocks of ``block_frames`` matched frames."""
        block, fill = self._new_block(), 0

        def flush():
            nonlocal block, fill
            out = FrameBlock(rgb=block.rgb[:fill], depth_mm=block.depth_mm[:fill],
                             T_world_camera=block.T_world_camera[:fill], stamp_ns=block.stamp_ns[:fill],
                             instance=None if block.instance is None else block.instance[:fill], start=self.n_out)
            self.n_out += fill
            block, fill = self._new_block(), 0
            return out

        def emit(final: bool):
            nonlocal fill
            for c, d, inst, T in self._decide(final):
                rgb, dep = c.array(), d.array()
                self._check_pair(c, rgb, d, dep)
                self._check_image(c, rgb, (np.dtype(np.uint8),), 3)
                self._check_image(d, dep, (np.dtype(np.uint16), np.dtype(np.float32), np.dtype(np.float64)), None)
                block.rgb[fill] = rgb
                block.depth_mm[fill] = self.depth_to_mm(dep)
                if inst is not None:
                    ins = inst.array()
                    self._check_pair(c, rgb, inst, ins)
                    self._check_image(inst, ins, (np.dtype(np.uint16),), None)
                    block.instance[fill] = ins
                block.T_world_camera[fill], block.stamp_ns[fill] = T, c.stamp_ns
                c.payload = d.payload = None  # the block holds the pixels now
                fill += 1
                if fill == self.params.block_frames:
                    yield flush()

        for s in samples:
            self._accept(s)
            if s.stream in IMAGE_STREAMS or s.stream == POSE:
                yield from emit(False)
        self.ended.update(self.streams)
        for tr in self.tracks.values():
            tr.ended = True
        yield from emit(True)
        for st in self.streams[1:]:
            while self.pending[st]:
                self.pending[st].popleft()
                self.unmatched[st]["no_rgb_within_tolerance"] += 1
        if fill:
            yield flush()

    def summary(self) -> dict:
        """Counts per stream, matched frames, unmatched messages by reason (stored as attrs 'matching')."""
        p = self.params
        return {
            "messages": dict(sorted(self.counts.items())),
            "matched_frames": self.n_out,
            "unmatched": {s: dict(sorted(c.items())) for s, c in self.unmatched.items()},
            "unmatched_rgb_message_ranges": {k: index_ranges(v) for k, v in sorted(self.unmatched_rgb_index.items())},
            "pose": {"chain": [lk.name for lk in self.info.pose_chain],
                     "static_links": [lk.name for lk in self.info.pose_chain if lk.static is not None],
                     **{f"frames_{k}": v for k, v in sorted(self.pose_how.items())}},
            "max_matched_dt_s": {k: v / NS for k, v in self.max_dt_ns.items() if k in self.streams},
            "tolerances": {"max_rgb_depth_dt_s": p.max_rgb_depth_dt_s, "max_pose_gap_s": p.max_pose_gap_s,
                           "max_pose_extrapolation_s": p.max_pose_extrapolation_s,
                           "max_stream_lag_s": p.max_stream_lag_s},
        }
