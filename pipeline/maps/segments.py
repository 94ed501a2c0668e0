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

SEGMENT_ROWS = 1 << 16  # rows of one segment: 128 MB at 512 features (its pages are taken as rows are written)


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

    def _split(self, slots: torch.Tensor) -> Iterator[tuple[torch.Tensor, torch.Tensor | slice | None, torch.Tensor]]:
        """``(segment, positions in slots or None for all of them, rows within the segment)`` per segment that
        ``slots`` ``(n,)`` int64 reach, in segment order; positions keep their order in ``slots`` (a slice when
        ``slots`` ascend, as a block's touched slots do: then no row is copied to be added)."""
        if not len(slots):
            return
        seg = slots >> self.shift
        lo, hi = int(seg.min()), int(seg.max())
        if lo == hi:
            yield self.segments[lo], None, slots - (lo << self.shift)
            return
        if bool((seg[1:] >= seg[:-1]).all()):
            bounds = torch.searchsorted(seg, torch.arange(lo, hi + 2, device=seg.device)).tolist()
            for s, start, stop in zip(range(lo, hi + 1), bounds, bounds[1:]):
                if start < stop:
                    yield self.segments[s], slice(start, stop), slots[start:stop] - (s << self.shift)
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


PAGE_CELLS = 64  # edge (cells) of the squares a TilePagedIndex allocates: 16 kB a square and height level


class TilePagedIndex:
    """An int32 entry per key of a voxel lattice (``level * rows * cols + row * cols + col`` on ``grid``), -1 until
    written; the memory of a square of :data:`PAGE_CELLS` cells at one level is taken when a key in it is first
    written. A voxel accumulator's slot of each key (:mod:`pipeline.maps.fusion`): a whole lattice of int32 is 4
    bytes per cell and level of the floor (200 MB on a 100 m x 60 m office at 5 cm and 21 levels) where a chunk of
    frames reaches a part of it. Indexed like a tensor by ``(n,)`` int64 keys (get and set; repeated keys in a
    set keep one of their values, as tensor indexing does)."""

    dtype = torch.int32

    def __init__(self, rows: int, cols: int, levels: int, device: torch.device):
        self.cols, self.cells, self.device = cols, rows * cols, torch.device(device)
        self.per_row = -(-cols // PAGE_CELLS)
        self.squares = -(-rows // PAGE_CELLS) * self.per_row
        self.page_of = torch.full((levels * self.squares,), -1, dtype=torch.int64, device=self.device)
        self.pages = 0
        self.entries = torch.empty(0, dtype=torch.int32, device=self.device)  # page p: [p * PAGE_CELLS^2, ...)

    def _page_and_offset(self, keys: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        level, cell = keys // self.cells, keys % self.cells
        row, col = cell // self.cols, cell % self.cols
        square = level * self.squares + (row // PAGE_CELLS) * self.per_row + col // PAGE_CELLS
        return square, (row % PAGE_CELLS) * PAGE_CELLS + col % PAGE_CELLS

    def __getitem__(self, keys: torch.Tensor) -> torch.Tensor:
        square, offset = self._page_and_offset(keys)
        page = self.page_of[square]
        out = torch.full(keys.shape, -1, dtype=torch.int32, device=self.device)
        held = torch.nonzero(page >= 0).squeeze(1)
        out[held] = self.entries[page[held] * PAGE_CELLS**2 + offset[held]]
        return out

    def __setitem__(self, keys: torch.Tensor, values: torch.Tensor) -> None:
        square, offset = self._page_and_offset(keys)
        new = torch.unique(square[self.page_of[square] < 0])
        if len(new):
            need = (self.pages + len(new)) * PAGE_CELLS**2
            if need > len(self.entries):  # grown by doubling: the copy is of the pages in use (kB per square)
                grown = torch.empty(max(need, 2 * len(self.entries)), dtype=torch.int32, device=self.device)
                grown[: len(self.entries)] = self.entries
                self.entries = grown
            self.entries[self.pages * PAGE_CELLS**2 : need] = -1
            self.page_of[new] = torch.arange(self.pages, self.pages + len(new), device=self.device)
            self.pages += len(new)
        self.entries[self.page_of[square] * PAGE_CELLS**2 + offset] = values.to(torch.int32)
