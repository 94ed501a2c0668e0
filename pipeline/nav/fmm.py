"""Geodesic shortest paths on the navigable grid with the fast marching method (scikit-fmm).

As in the paper and navchat: the travel distance to a goal region is the FMM distance field on the
navigable mask; a path follows its steepest descent from the start cell and is then shortened
(string pulling over the same mask) into a polyline in world metres.

Arrays are ``(rows, cols)`` on a :class:`~pipeline.geometry.GridSpec`; distances in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import skfmm
from scipy import ndimage

from pipeline.geometry import GridSpec

_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])
_STEPS = np.linalg.norm(_NEIGHBOURS, axis=1)
_STEP_LIST: list[float] = _STEPS.tolist()
_MOVES: list[tuple[int, int]] = [(int(dr), int(dc)) for dr, dc in _NEIGHBOURS]
_SAMPLES: dict[int, np.ndarray] = {}
_SAMPLE_LISTS: dict[int, list[float]] = {}


def planning_mask(navigable: np.ndarray, grid: GridSpec, clearance_m: float) -> np.ndarray:
    """Navigable cells at least ``clearance_m`` from any non-navigable cell (or the grid edge)."""
    nav = np.asarray(navigable, dtype=bool)
    if clearance_m <= 0:
        return nav.copy()
    padded = np.pad(nav, 1, constant_values=False)
    dist = ndimage.distance_transform_edt(padded)[1:-1, 1:-1] * grid.cell_size_m
    # a cell centre is ``dist - cell/2`` from the nearest blocked cell's edge
    return nav & (dist - 0.5 * grid.cell_size_m >= clearance_m - 1e-9)


def target_region(plan_mask: np.ndarray, object_mask: np.ndarray, grid: GridSpec, stop_radius_m: float
                  ) -> np.ndarray:
    """Plannable cells whose centre is within ``stop_radius_m`` of the object's footprint cells."""
    obj = np.asarray(object_mask, dtype=bool)
    plan_mask = np.asarray(plan_mask, dtype=bool)
    if not obj.any():
        return np.zeros_like(plan_mask, dtype=bool)
    if stop_radius_m <= 0:  # the footprint's own cells (distance 0): no distance transform
        return plan_mask & obj if stop_radius_m == 0 else np.zeros_like(plan_mask, dtype=bool)
    # the distance transform on the footprint's box grown past the radius: every cell within it lies there, and
    # the nearest footprint cell of each is in it, so the distances are the whole grid's
    pad = int(np.ceil(stop_radius_m / grid.cell_size_m)) + 1
    rr, cc = np.nonzero(obj)
    win = (slice(max(int(rr.min()) - pad, 0), int(rr.max()) + pad + 1),
           slice(max(int(cc.min()) - pad, 0), int(cc.max()) + pad + 1))
    out = np.zeros_like(plan_mask, dtype=bool)
    dist = ndimage.distance_transform_edt(~obj[win]) * grid.cell_size_m
    out[win] = plan_mask[win] & (dist <= stop_radius_m)
    return out


def geodesic_field(plan_mask: np.ndarray, target: np.ndarray, grid: GridSpec) -> np.ndarray:
    """FMM travel distance (metres) to ``target`` inside ``plan_mask``; 0 on the target, inf where unreachable."""
    plan_mask = np.asarray(plan_mask, dtype=bool)
    target = np.asarray(target, dtype=bool) & plan_mask
    out = np.full(plan_mask.shape, np.inf)
    if not target.any():
        return out
    if target.all() or target[plan_mask].all():
        out[target] = 0.0
        return out
    phi = np.ma.MaskedArray(np.where(target, -1.0, 1.0), mask=~plan_mask)
    try:
        dist = skfmm.distance(phi, dx=grid.cell_size_m)
    except ValueError:  # the target touches no free cell (an enclosed pocket): only itself is reachable
        out[target] = 0.0
        return out
    field = np.asarray(np.ma.filled(dist, np.inf), dtype=np.float64)  # our own array: not copied again
    field[target] = 0.0
    field[~plan_mask] = np.inf
    return field


def reachable(plan_mask: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(rows, cols)`` bool: the cells :func:`geodesic_field` leaves finite, found without marching — the cells of
    ``plan_mask`` joined to a cell of ``target & plan_mask`` by steps between 4-neighbours in ``plan_mask`` (the fast
    marching stencil's neighbours; a target that touches no other free cell reaches only itself, as there)."""
    labels = mask_parts(plan_mask)
    return joined_parts(labels, target)[labels]


def mask_parts(plan_mask: np.ndarray) -> np.ndarray:
    """``(rows, cols)`` int32: the 4-connected parts of ``plan_mask`` numbered from 1 (0 off the mask)."""
    return ndimage.label(np.asarray(plan_mask, dtype=bool))[0]


def joined_parts(labels: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(parts + 1,)`` bool: the parts of :func:`mask_parts` ``labels`` holding a cell of ``target`` (never 0)."""
    joined = np.zeros(int(labels.max(initial=0)) + 1, bool)
    joined[labels[np.asarray(target, dtype=bool)]] = True
    joined[0] = False
    return joined


def descend(field: np.ndarray, start_rc: tuple[int, int], max_steps: int | None = None) -> np.ndarray:
    """Cells ``(K,2)`` from ``start_rc`` down the distance field to a cell with value 0 (8-connected).

    Moves to the neighbour with the smallest ``field + step length`` ordering (steepest descent);
    stops at the target, or raises ``ValueError`` at a local minimum (never expected for FMM fields).
    Inner cells read their 8 neighbours with one flat gather; cells on the grid's edge treat the
    neighbours off the grid as unreachable (the same rule, spelled out).
    """
    rows, cols = field.shape
    r, c = int(start_rc[0]), int(start_rc[1])
    if not np.isfinite(field[r, c]):
        raise ValueError(f"start cell {(r, c)} cannot reach the target")
    path = [(r, c)]
    max_steps = max_steps or rows * cols
    flat = np.ascontiguousarray(field).ravel()
    offsets = _NEIGHBOURS[:, 0] * cols + _NEIGHBOURS[:, 1]
    f = float(field[r, c])
    for _ in range(max_steps):
        if f <= 0:
            return np.array(path)
        if 0 < r < rows - 1 and 0 < c < cols - 1:
            vals = flat[r * cols + c + offsets].tolist()
        else:
            nb = _NEIGHBOURS + (r, c)
            ok = (nb[:, 0] >= 0) & (nb[:, 0] < rows) & (nb[:, 1] >= 0) & (nb[:, 1] < cols)
            edge = np.full(8, np.inf)
            edge[ok] = field[nb[ok, 0], nb[ok, 1]]
            vals = edge.tolist()
        k = _steepest(f, vals)
        if not (vals[k] < f):
            raise ValueError(f"descent stuck at cell {(r, c)} (field {f:.3f})")
        r, c, f = r + _MOVES[k][0], c + _MOVES[k][1], vals[k]
        path.append((r, c))
    raise ValueError("descent did not reach the target")


def _steepest(f: float, vals: list[float]) -> int:
    """``argmax((f - vals) / step length)`` over the 8 neighbours (the first of equals; a NaN wins, as in numpy),
    in plain floats: the same IEEE operations as the array expression, without its per-step overhead."""
    best_k, best = 0, (f - vals[0]) / _STEP_LIST[0]
    if best != best:
        return 0
    for k in range(1, 8):
        slope = (f - vals[k]) / _STEP_LIST[k]
        if slope != slope:
            return k
        if slope > best:
            best_k, best = k, slope
    return best_k


def _samples(n: int) -> np.ndarray:
    """``np.linspace(0, 1, n)``, computed once per ``n``."""
    t = _SAMPLES.get(n)
    if t is None:
        t = _SAMPLES[n] = np.linspace(0.0, 1.0, n)
    return t


def _segments_free(mask: np.ndarray, a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """``(N,)`` bool: the ``n`` evenly spaced samples of each segment ``a[i] -> b[i]`` (``(N,2)`` continuous cell
    coordinates) all lie in a True cell of ``mask``."""
    pts = a[:, None] + (b - a)[:, None] * _samples(n)[None, :, None]  # (N,n,2)
    idx = np.floor(pts + 0.5).astype(np.int64)
    rows, cols = mask.shape
    r, c = idx[..., 0], idx[..., 1]
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    return (inside & mask[np.minimum(np.maximum(r, 0), rows - 1), np.minimum(np.maximum(c, 0), cols - 1)]).all(axis=1)


def _sample_count(a: np.ndarray, b: np.ndarray) -> int:
    """Samples per segment of a batch: every 1/3 cell along the longest one, ends included."""
    d = b - a
    return int(np.ceil(np.sqrt((d * d).sum(axis=1)).max(initial=0.0) * 3)) + 2


def segment_free(mask: np.ndarray, a_rc: np.ndarray, b_rc: np.ndarray) -> np.ndarray:
    """For segments between continuous cell coordinates ``(N,2)`` -> ``(N,)`` bool: every sample on the
    segment (every 1/3 cell of the batch's longest segment) lies in a True cell of ``mask``."""
    a = np.asarray(a_rc, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b_rc, dtype=np.float64).reshape(-1, 2)
    if len(a) == 1:  # one segment (an agent's step): the same samples in plain floats, no array overhead
        return np.array([one_segment_free(mask, *a[0].tolist(), *b[0].tolist())])
    return _segments_free(mask, a, b, _sample_count(a, b))


def one_segment_free(mask: np.ndarray, a0: float, a1: float, b0: float, b1: float) -> bool:
    """:func:`segment_free` of the one segment from continuous cell coordinates ``(a0, a1)`` to ``(b0, b1)`` (plain
    floats: an agent's step, checked without array overhead)."""
    d0, d1 = b0 - a0, b1 - a1
    n = int(math.ceil(math.sqrt(d0 * d0 + d1 * d1) * 3)) + 2
    rows, cols = mask.shape
    ts = _sample_list(n)
    if _monotone(n):  # every sample lies in the box of the first and the last one's cells (see _first_blocked)
        r0, c0 = math.floor(a0 + d0 * ts[0] + 0.5), math.floor(a1 + d1 * ts[0] + 0.5)
        r1, c1 = math.floor(a0 + d0 * ts[-1] + 0.5), math.floor(a1 + d1 * ts[-1] + 0.5)
        if (0 <= min(r0, r1) and max(r0, r1) < rows and 0 <= min(c0, c1) and max(c0, c1) < cols
                and mask[min(r0, r1): max(r0, r1) + 1, min(c0, c1): max(c0, c1) + 1].all()):
            return True
    last = None
    for t in ts:
        rc = (math.floor(a0 + d0 * t + 0.5), math.floor(a1 + d1 * t + 0.5))
        if rc != last:  # samples in the cell just read: the same answer
            if not (0 <= rc[0] < rows and 0 <= rc[1] < cols and mask[rc]):
                return False
            last = rc
    return True


def _sample_list(n: int) -> list[float]:
    """``_samples(n)`` as plain floats, computed once per ``n``."""
    t = _SAMPLE_LISTS.get(n)
    if t is None:
        t = _SAMPLE_LISTS[n] = _samples(n).tolist()
    return t


def _first_blocked(mask: np.ndarray, a: np.ndarray, b: np.ndarray, n: int) -> int | None:
    """The first ``i`` whose segment ``a[i] -> b[i]`` (``(N,2)``) :func:`_segments_free` finds blocked with ``n``
    samples, or None — reading a fraction of the samples, with the same verdicts.

    Along a segment each sample's row ``floor(a + (b - a) * t + 0.5)`` never decreases (or never increases) with
    ``t``, and so does its column: the samples between two samples lie in the box of those two cells. So only every
    ``stride``-th sample is computed (the same expression on the same ``t``, spaced about a cell apart on the
    longest segment); the samples between two of them are computed only where that box holds a cell off
    ``mask`` (a diagonal step past a corner) or spans more than two cells a side."""
    t = _samples(n)
    length = float(np.sqrt(((b - a) ** 2).sum(axis=1)).max(initial=0.0))
    stride = max(1, int((n - 1) // max(length, 1.0)))
    if stride < 4 or not _monotone(n):  # few samples to skip: the plain test
        blocked = np.flatnonzero(~_segments_free(mask, a, b, n))
        return int(blocked[0]) if blocked.size else None
    ks = np.arange(0, n, stride)
    if ks[-1] != n - 1:
        ks = np.append(ks, n - 1)
    rows, cols = mask.shape
    idx = np.floor(a[:, None] + (b - a)[:, None] * t[ks][None, :, None] + 0.5).astype(np.int64)  # (N, m, 2)
    r, c = idx[..., 0], idx[..., 1]
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    rc_, cc_ = np.clip(r, 0, rows - 1), np.clip(c, 0, cols - 1)
    free = inside & mask[rc_, cc_]
    blocked = ~free.all(axis=1)
    # consecutive samples both free: the box between them is their two cells and the two corner cells when it spans
    # at most two cells a side; otherwise (a corner off the mask, or a wider box) the samples between are computed
    r0, r1, c0, c1 = rc_[:, :-1], rc_[:, 1:], cc_[:, :-1], cc_[:, 1:]
    moved = (r0 != r1) & (c0 != c1)
    wide = (np.abs(r1 - r0) > 1) | (np.abs(c1 - c0) > 1)
    check = free[:, :-1] & free[:, 1:] & (wide | (moved & ~(mask[r0, c1] & mask[r1, c0])))
    check &= ~blocked[:, None]
    seg, gap = np.nonzero(check)
    if seg.size:  # the samples between, all such gaps at once (the last gap may be shorter: padded, not counted)
        k = ks[gap][:, None] + np.arange(1, stride)[None, :]
        real = k < ks[gap + 1][:, None]
        tk = t[np.minimum(k, n - 1)]
        pts = np.floor(a[seg][:, None] + (b - a)[seg][:, None] * tk[..., None] + 0.5).astype(np.int64)
        pr, pc = pts[..., 0], pts[..., 1]
        ok = (pr >= 0) & (pr < rows) & (pc >= 0) & (pc < cols)
        ok &= mask[np.clip(pr, 0, rows - 1), np.clip(pc, 0, cols - 1)]
        blocked[seg[~(ok | ~real).all(axis=1)]] = True
    hit = np.flatnonzero(blocked)
    return int(hit[0]) if hit.size else None


_MONOTONE: dict[int, bool] = {}


def _monotone(n: int) -> bool:
    """Whether ``_samples(n)`` never decreases (what :func:`_first_blocked` relies on; numpy's linspace does)."""
    ok = _MONOTONE.get(n)
    if ok is None:
        ok = _MONOTONE[n] = bool((np.diff(_samples(n)) >= 0).all())
    return ok


def shortcut(cells: np.ndarray, mask: np.ndarray, chunk: int = 32) -> np.ndarray:
    """String pulling: keep the fewest cells of the path such that each kept segment stays in ``mask``.

    From each kept cell, the segments to all later cells are tested (sampled as one batch, as
    :func:`segment_free` samples it) in runs of ``chunk``, stopping at the first run with a blocked one:
    only the visible run up to the first blocked cell matters.
    """
    cells = np.asarray(cells)
    if len(cells) <= 2:
        return cells
    keep = [0]
    i = 0
    while i < len(cells) - 1:
        later = cells[i + 1 :].astype(np.float64)
        start = np.repeat(cells[i : i + 1].astype(np.float64), len(later), 0)
        n = _sample_count(start, later)  # the batch's sampling, whatever run is tested
        first_blocked = None
        for s in range(0, len(later), chunk):
            blocked = _first_blocked(mask, start[s : s + chunk], later[s : s + chunk], n)
            if blocked is not None:
                first_blocked = s + blocked
                break
        # the first blocked index bounds the visible run along the path
        j = i + 1 + (first_blocked - 1 if first_blocked is not None else len(later) - 1)
        j = max(j, i + 1)
        keep.append(j)
        i = j
    return cells[keep]


@dataclass
class GeodesicPath:
    """A shortest path: polyline in world metres and its lengths."""

    polyline_xy: np.ndarray  # (K,2) float64, world metres, start first
    geodesic_m: float  # FMM distance from the start cell to the goal region
    length_m: float  # length of the polyline

    @staticmethod
    def polyline_length(xy: np.ndarray) -> float:
        return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def shortest_path(field: np.ndarray, plan_mask: np.ndarray, grid: GridSpec, start_xy: np.ndarray
                  ) -> GeodesicPath | None:
    """The shortest path from ``start_xy`` (world) down ``field``; ``None`` when unreachable.

    The polyline starts at ``start_xy`` itself, then follows shortened cell centres.
    """
    start_xy = np.asarray(start_xy, dtype=np.float64)
    rc = grid.world_to_cell(start_xy)
    if not grid.inside(rc) or not np.isfinite(field[rc[0], rc[1]]):
        return None
    cells = shortcut(descend(field, (int(rc[0]), int(rc[1]))), plan_mask)
    xy = grid.cell_to_world(cells)
    xy[0] = start_xy
    return GeodesicPath(xy, float(field[rc[0], rc[1]]), GeodesicPath.polyline_length(xy))
