"""The scene's surface points in parts, read a chunk at a time: reconstruct's steps after fusion (the floors, the
grid's placement, each floor's grids, the stairs, the points file) stream over them, so their memory is bounded by
a chunk or a tile, not by the floor's area.

A tiled fusion (:mod:`pipeline.recon.tiles`) spills each tile's points (:meth:`Surface.add`, sorted in
:func:`pipeline.recon.store.canonical_point_order`) to three ``.npy`` files; one volume's points are one part held
in memory (:meth:`Surface.of`). Every consumer gives the result it gives on the whole arrays, whatever the parts:

- counts, histograms on a fixed origin, per-cell maxima and masks add up chunk by chunk;
- an order statistic (a median, a percentile) is selected exactly in two passes (:func:`order_statistics`: a
  radix select on the float32 values' bits), no value held but those of one 16-bit bucket;
- a test that looks a few centimetres around a cell reads the points of the cell's tile and of its neighbours
  within reach (:meth:`Surface.near`);
- the points file merges the parts slab by slab along x into the one canonical order (:meth:`Surface.write_ply`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np

from pipeline.errors import ArtifactError

CHUNK = 1 << 20  # points read at once
_SLAB_M = 0.5  # the points file is merged in slabs of this width along x
COLUMNS = ("xyz", "normals", "colors")


@dataclass
class Part:
    """One tile's surface points in canonical order: in memory (``arrays``) or spilled (``files``), with the
    contiguous x of each point (the merge's key) and the points' xy box."""

    tile: tuple[int, int]
    count: int
    box: tuple[float, float, float, float]  # x0, x1, y0, y1 of its points
    arrays: dict[str, np.ndarray] | None = None
    files: dict[str, Path] | None = None

    def read(self, column: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows ``start:stop`` of ``column`` (``xyz``, ``normals``, ``colors`` or ``x``), copied out.

        A spilled file is mapped only while its rows are copied: the pages of a long-lived map stay resident and
        would count in the process's memory."""
        if self.arrays is not None:
            return self.arrays[column][start:stop]
        rows = np.load(self.files[column], mmap_mode="r")
        out = np.array(rows[start:stop])
        del rows
        return out

    def x_range(self, lo: float, hi: float) -> tuple[int, int]:
        """The rows whose x lies in ``[lo, hi)`` (rows are sorted by x): ``(start, stop)``.

        The bounds are searched as float32 (a float64 key would convert the whole column): each rounded up to the
        least float32 not below it, which keeps exactly the float32 values not below the float64 bound."""
        x = self.arrays["x"] if self.arrays is not None else np.load(self.files["x"], mmap_mode="r")
        span = int(np.searchsorted(x, _ceil32(lo))), int(np.searchsorted(x, _ceil32(hi)))
        del x
        return span


def _ceil32(v: float) -> np.float32:
    """The least float32 not below ``v``."""
    f = np.float32(v)
    return np.nextafter(f, np.float32(np.inf)) if f < v else f


class Surface:
    """The surface points (positions float32 ``(N,3)``, normals float32, colours uint8) of a scene, in parts.

    ``owner(xy)`` maps world points to the tile owning them (:meth:`pipeline.recon.tiles.TileLayout.owner`);
    without it the whole plane is one tile ``(0, 0)``.
    """

    def __init__(self, owner: Callable[[np.ndarray], np.ndarray] | None = None, workdir: Path | None = None):
        self.parts: dict[tuple[int, int], Part] = {}
        self._owner = owner
        self._workdir = workdir

    @classmethod
    def of(cls, xyz: np.ndarray, normals: np.ndarray, colors: np.ndarray | None = None) -> Surface:
        """One part in memory: the points of one volume (``colors`` default black)."""
        surface = cls()
        surface.add((0, 0), xyz, normals, np.zeros(np.shape(xyz), np.uint8) if colors is None else colors)
        return surface

    def add(self, tile: tuple[int, int], xyz: np.ndarray, normals: np.ndarray, colors: np.ndarray) -> None:
        """The points ``tile`` owns, put in canonical order (spilled under the workdir when there is one)."""
        from pipeline.recon.store import canonical_point_order

        if not len(xyz):
            return
        order = canonical_point_order(xyz, normals, colors)
        arrays = {"xyz": np.ascontiguousarray(xyz[order], np.float32),
                  "normals": np.ascontiguousarray(normals[order], np.float32),
                  "colors": np.ascontiguousarray(colors[order], np.uint8)}
        arrays["x"] = np.ascontiguousarray(arrays["xyz"][:, 0])
        box = (float(arrays["x"][0]), float(arrays["x"][-1]), float(arrays["xyz"][:, 1].min()),
               float(arrays["xyz"][:, 1].max()))
        part = Part(tile, len(order), box)
        if self._workdir is None:
            part.arrays = arrays
        else:
            part.files = {k: self._workdir / f"points_{tile[0]}_{tile[1]}.{k}.npy" for k in arrays}
            for k, a in arrays.items():
                np.save(part.files[k], a)
        self.parts[tile] = part

    @property
    def count(self) -> int:
        return sum(p.count for p in self.parts.values())

    def chunks(self, columns: Iterable[str] = COLUMNS, tiles: Iterable[tuple[int, int]] | None = None
               ) -> Iterator[tuple[np.ndarray, ...]]:
        """The points ``CHUNK`` at a time as a tuple of ``columns`` (of ``tiles``, default every part)."""
        columns = tuple(columns)
        for tile in (self.parts if tiles is None else tiles):
            part = self.parts.get(tile)
            if part is None:
                continue
            for s in range(0, part.count, CHUNK):
                yield tuple(part.read(c, s, s + CHUNK) for c in columns)

    def tile_of(self, xy: np.ndarray) -> np.ndarray:
        """``(N, 2)`` int: the tile owning each world point ``(N, 2)``."""
        if self._owner is None:
            return np.zeros((len(xy), 2), np.int64)
        return self._owner(xy)

    def near(self, tile: tuple[int, int], box: tuple[float, float, float, float],
             columns: Iterable[str] = COLUMNS) -> tuple[np.ndarray, ...]:
        """The points of ``tile`` and of its eight neighbours whose xy lies in ``box`` (x0, x1, y0, y1, closed):
        all the points within reach of the tile's cells when ``box`` reaches less than a tile past them."""
        columns = tuple(columns)
        x0, x1, y0, y1 = box
        out = [[] for _ in columns]
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                part = self.parts.get((tile[0] + di, tile[1] + dj))
                if part is None or part.box[0] > x1 or part.box[1] < x0 or part.box[2] > y1 or part.box[3] < y0:
                    continue
                start, stop = part.x_range(x0, np.nextafter(_ceil32(x1), np.float32(np.inf)))
                for s in range(start, stop, CHUNK):
                    e = min(stop, s + CHUNK)
                    xyz = part.read("xyz", s, e)
                    keep = (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
                    for k, c in enumerate(columns):
                        out[k].append((xyz if c == "xyz" else part.read(c, s, e))[keep])
        return tuple(np.concatenate(o) if o else _empty(c) for o, c in zip(out, columns))

    def write_ply(self, path: Path) -> dict:
        """The points as a binary PLY in canonical order: the bytes :func:`pipeline.recon.store.write_points` writes
        for the whole arrays, merged slab by slab along x (each part is sorted by x first, so a slab's rows are one
        run of each part)."""
        from pipeline.recon.store import canonical_point_order
        from pipeline.recon.tiled_mesh import ply_header, vertex_records

        parts = sorted(self.parts.values(), key=lambda p: p.box[0])
        n = self.count
        try:
            with open(path, "wb") as out:
                out.write(ply_header(n, None))
                if len(parts) == 1:
                    for xyz, normals, colors in self.chunks():
                        out.write(_records(vertex_records, xyz, normals, colors))
                elif parts:
                    x0, x1 = min(p.box[0] for p in parts), max(p.box[1] for p in parts)
                    cuts = x0 + _SLAB_M * np.arange(int(np.floor((x1 - x0) / _SLAB_M)) + 2)
                    cuts[-1] = np.inf  # the last slab takes every point left, whatever the rounding
                    for lo, hi in zip(cuts[:-1], cuts[1:]):
                        rows = [[], [], []]
                        for part in parts:
                            if part.box[0] >= hi or part.box[1] < lo:
                                continue
                            start, stop = part.x_range(lo, hi)
                            if stop > start:
                                for k, c in enumerate(COLUMNS):
                                    rows[k].append(part.read(c, start, stop))
                        if rows[0]:
                            xyz, normals, colors = (np.concatenate(r) for r in rows)
                            order = canonical_point_order(xyz, normals, colors)
                            out.write(_records(vertex_records, xyz[order], normals[order], colors[order]))
        except OSError as e:
            raise ArtifactError(f"{path}: could not write the point cloud: {e}") from e
        return {"file": Path(path).name, "count": int(n)}


def _records(vertex_records, xyz, normals, colors) -> bytes:
    return vertex_records(xyz.astype(np.float64), normals.astype(np.float64),
                          colors.astype(np.float64) / 255.0).tobytes()


def _empty(column: str) -> np.ndarray:
    return np.zeros((0, 3), np.uint8 if column == "colors" else np.float32) if column != "x" else np.zeros(0, np.float32)


# ----------------------------------------------------------------------------- exact order statistics

def _sortable(values: np.ndarray) -> np.ndarray:
    """uint32 keys ordered as the float32 ``values`` are (no NaN)."""
    bits = np.ascontiguousarray(values, np.float32).view(np.uint32)
    return np.where(bits >> 31 == 1, ~bits, bits | np.uint32(1 << 31))


def order_statistics(values: Callable[[], Iterable[np.ndarray]], ranks: Iterable[int]) -> dict[int, np.float32]:
    """The values at 0-based ``ranks`` of the sorted float32 values ``values()`` yields (chunks, any order), exactly:
    a radix select over their bits in two passes (a histogram of the high 16 bits, then of the low 16 of the
    buckets holding the ranks), holding 2 x 65536 counts, never the values."""
    ranks = sorted(set(int(r) for r in ranks))
    high = np.zeros(1 << 16, np.int64)
    for chunk in values():
        high += np.bincount(_sortable(chunk) >> 16, minlength=1 << 16)
    cum = np.cumsum(high)
    if not ranks:
        return {}
    if ranks[0] < 0 or ranks[-1] >= cum[-1]:
        raise ValueError(f"ranks {ranks[0]}..{ranks[-1]} outside 0..{int(cum[-1]) - 1}")
    bucket = {r: int(np.searchsorted(cum, r, side="right")) for r in ranks}
    low = {b: np.zeros(1 << 16, np.int64) for b in set(bucket.values())}
    for chunk in values():
        keys = _sortable(chunk)
        for b, counts in low.items():
            counts += np.bincount(keys[keys >> 16 == b] & 0xFFFF, minlength=1 << 16)
    out = {}
    for r in ranks:
        b = bucket[r]
        before = int(cum[b - 1]) if b else 0
        lo16 = int(np.searchsorted(np.cumsum(low[b]), r - before, side="right"))
        key = np.uint32((b << 16) | lo16)
        bits = np.where(key >> 31 == 1, key & np.uint32(0x7FFFFFFF), ~key)
        out[r] = np.asarray(bits, np.uint32).view(np.float32)[()]
    return out


def count(values: Callable[[], Iterable[np.ndarray]]) -> int:
    return sum(len(v) for v in values())


def median(values: Callable[[], Iterable[np.ndarray]], n: int | None = None) -> float:
    """``np.median`` of the float32 values (as float64) ``values()`` yields, exactly (:func:`order_statistics`)."""
    n = count(values) if n is None else n
    picked = order_statistics(values, {(n - 1) // 2, n // 2})
    return float(np.median(np.array([picked[(n - 1) // 2], picked[n // 2]], np.float64)))


def percentiles(values: Callable[[], Iterable[np.ndarray]], q: Iterable[float], n: int | None = None) -> np.ndarray:
    """``np.percentile(v, q)`` (linear) of the float32 values ``v`` that ``values()`` yields, exactly: the order
    statistics either side of each virtual index, interpolated as numpy's ``_lerp`` does."""
    n = count(values) if n is None else n
    quantiles = np.true_divide(np.asarray(list(q), np.float64), 100)
    virtual = (n - 1) * quantiles
    previous = np.floor(virtual)
    following = previous + 1
    above, below = virtual >= n - 1, virtual < 0
    previous[above], following[above] = n - 1, n - 1
    previous[below], following[below] = 0, 0
    gamma = np.asanyarray(virtual - np.floor(virtual), dtype=virtual.dtype)
    picked = order_statistics(values, np.r_[previous, following].astype(np.int64))
    a = np.array([picked[int(i)] for i in previous], np.float32)
    b = np.array([picked[int(i)] for i in following], np.float32)
    diff_b_a = b - a
    out = np.add(a, diff_b_a * gamma)
    np.subtract(b, diff_b_a * (1 - gamma), out=out, where=gamma >= 0.5, casting="unsafe", dtype=type(out.dtype))
    return out
