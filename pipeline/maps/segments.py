"""A growable table of float32 rows held in fixed segments: an accumulator's feature sums (:mod:`pipeline.maps.fusion`).

The sums of a map's accumulator are its largest part (2 kB a row at 512 features). Grown as one tensor doubled and
copied, a growth held the old rows and their copy at once: twice the sums, at the moment they are largest (a chunk
of a 100 m x 60 m office's walk reaches 300,000 to 600,000 cells or voxels, 0.6 to 1.2 GB of sums). Here the
table grows by whole segments of :data:`SEGMENT_ROWS` rows and never copies a row: its memory is the rows given
out (a segment's pages are taken by the system as they are first written), plus at most one segment's.

Every operation reads or writes each row it names once and in the order it is named, segment by segment, so the
results are those of the same operation on one tensor, bit for bit: :meth:`SegmentedRows.index_add_` adds into a
row in the order of its occurrences in ``slots``.
"""

from __future__ import annotations

from typing import Iterator

import torch

SEGMENT_ROWS = 1 << 15  # rows of one segment: 64 MB at 512 features


class SegmentedRows:
    """A ``(capacity, dim)`` float32 table on ``device`` in segments of ``segment_rows`` (a power of two; default
    :data:`SEGMENT_ROWS`); :meth:`reserve` grows it. Rows are unwritten until set."""

    def __init__(self, dim: int, device: torch.device, capacity: int = 0, segment_rows: int | None = None):
        segment_rows = SEGMENT_ROWS if segment_rows is None else segment_rows
        if segment_rows <= 0 or segment_rows & (segment_rows - 1):
            raise ValueError(f"segment_rows must be a power of two, got {segment_rows}")
        self.dim, self.device = dim, torch.device(device)
        self.shift = segment_rows.bit_length() - 1
        self.segments: list[torch.Tensor] = []
        self.reserve(capacity)

    @property
    def capacity(self) -> int:
        return len(self.segments) << self.shift

    def reserve(self, rows: int) -> None:
        """Grow (by whole segments, copying nothing) until ``rows`` rows fit."""
        while self.capacity < rows:
            self.segments.append(torch.empty((1 << self.shift, self.dim), dtype=torch.float32, device=self.device))

    def _split(self, slots: torch.Tensor) -> Iterator[tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]]:
        """``(segment, positions in slots or None for all of them, rows within the segment)`` per segment that
        ``slots`` ``(n,)`` int64 reach, in segment order; positions keep their order in ``slots``."""
        if not len(slots):
            return
        seg = slots >> self.shift
        lo, hi = int(seg.min()), int(seg.max())
        if lo == hi:
            yield self.segments[lo], None, slots - (lo << self.shift)
            return
        for s in torch.unique(seg).tolist():
            pos = torch.nonzero(seg == s).squeeze(1)
            yield self.segments[s], pos, slots[pos] - (s << self.shift)

    def zero_(self, slots: torch.Tensor) -> None:
        """Set rows ``slots`` to zero."""
        for segment, _, rows in self._split(slots):
            segment[rows] = 0

    def zero_range_(self, start: int, stop: int) -> None:
        """Set rows ``[start, stop)`` to zero."""
        size = 1 << self.shift
        for s in range(start >> self.shift, -(-stop // size)):
            self.segments[s][max(start - s * size, 0) : min(stop - s * size, size)] = 0

    def index_add_(self, slots: torch.Tensor, rows: torch.Tensor) -> None:
        """Add ``rows`` ``(n, dim)`` into rows ``slots`` ``(n,)`` (repeats add in their order)."""
        for segment, pos, local in self._split(slots):
            segment.index_add_(0, local, rows if pos is None else rows[pos])

    def gather(self, slots: torch.Tensor) -> torch.Tensor:
        """A copy of rows ``slots`` ``(n,)``: ``(n, dim)``."""
        out = None
        for segment, pos, local in self._split(slots):
            if pos is None:
                return torch.index_select(segment, 0, local)
            if out is None:
                out = torch.empty((len(slots), self.dim), dtype=torch.float32, device=self.device)
            out[pos] = segment[local]
        return torch.empty((0, self.dim), dtype=torch.float32, device=self.device) if out is None else out
