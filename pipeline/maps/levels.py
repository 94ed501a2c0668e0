"""Level-aware query scores of a cfmap: each cell scored by its BEST height level for the query.

The top-down map keeps one feature per cell, the highest level's (the height rule of
:mod:`pipeline.maps.fusion`). That hides what lies below a cell's top: a picture or a TV on a wall
whose top is the wall, a chair under a desk, a laptop under a shelf. The cfmap also stores its
sparse voxel map (``voxels/``, one feature per (row, col, level)), so a query can score every
voxel and give each cell the level where the query is most probable:

    logit_v = s_v / T - logsumexp_b(s_vb / T)        (s_v = f_v . q, s_vb = f_v . t_b, b = background prompts)
    cell c takes the voxel v* = argmax_{v in c} logit_v  (lowest voxel on ties)

and reports that voxel's query score, background max and background logsumexp, the three
arrays :class:`~pipeline.maps.query.MapQuery` turns into its heatmap and winning cells (so the
heatmap is ``max over levels`` of the query probability). Cells without voxels (filled by
``maps.fill_radius_m``) keep their top-down values.

Streaming: the voxel arrays are read one block of ``chunk_rows`` rows at a time (``voxels/features`` is stored in
chunks of ``tile_cells``² rows, 4,096 by default, so a block is one stored chunk), each block is scored (its float16
features upcast once, the query and the background prompts each one product) and reduced into per-cell running
best values. Memory is one block (8 MB of float32 at D = 512) plus four values per cell scored, never a value per
voxel. The background scores are computed in the same pass at every query (nothing per voxel is cached): on a map too
large to hold, that is one more product per block, 18.7 s a call against 11.4 s without background prompts on the
100 m x 60 m office (docs/buildings.md). Blocks start at multiples of ``chunk_rows`` of the stored voxel rows, so
every product has the shape it has over the whole array and the scores are the same bytes
(:func:`~pipeline.maps.scoring.chunked_scores_each`); a cell whose voxels straddle two blocks keeps the earlier
block's voxel on ties, as the whole-array argmax does.

Regions: ``voxels/`` rows ascend by (row, col, level), so a window's voxels lie in the rows of its band of grid rows;
the first and last key of every block (found by one pass over the keys, kept as 12 bytes a block) tell which blocks
can hold a cell of the window; of those, each block's keys (6 bytes a voxel) are read and its features (1 kB a voxel
at D = 512) only when a key lies in the window. A narrow window (a few columns of a wide floor) thus reads the keys
of its band of grid rows but the features of its own voxels' blocks only.

From the second call on, a map whose voxel features fit ``hold_mb`` (float16, as stored) keeps them and the keys in
memory, and the per-voxel background max and logsumexp of one background set at a time (8 bytes a voxel, 1/128 of
the held features at D = 512), so repeated queries skip reading, decoding and the background product (the same
blocks, the same scores).

Used by :class:`~pipeline.maps.query.MapQuery` when ``query.levels`` is ``max`` and the map stores
voxels (``top``, the default, scores the top-down features only). Everything is numpy: a query on a
map needs no torch.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import ArtifactError
from pipeline.maps.scoring import chunked_scores_each, logsumexp
from pipeline.maps.store import SemanticMap
from pipeline.region import Window, whole


class LevelScorer:
    """Best-level scores of a map's voxels per cell, read block by block (see the module docstring).

    ``chunk_rows``: voxel rows per block (and per product); ``hold_mb``: from the second call on, voxel features of
    at most this many MB (float16) are held in memory (0: always read block by block).
    """

    def __init__(self, smap: SemanticMap, *, chunk_rows: int = 4096, hold_mb: float = 0.0):
        if not smap.has_voxels:
            raise ArtifactError(f"{smap.path}: no voxels/ group; level-aware queries (query.levels: max) need a "
                                f"cfmap built with maps.cfmap_voxels: true (rebuild: zipon run --force --stage cfmap)")
        self.map = smap
        self.key, self.features = smap.group["voxels"]["key"], smap.group["voxels"]["features"]
        self.chunk_rows = chunk_rows
        self.hold_mb = hold_mb
        self.n_voxels = int(self.key.shape[0])
        self._bounds: np.ndarray | None = None  # (B,2,3) int16 first and last key of each block, read when needed
        self._held: tuple[np.ndarray, np.ndarray] | None = None  # (M,3) keys, (M,D) float16 features (hold_mb)
        self._bg: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}  # of the held features: one background set
        self._calls = 0

    @property
    def held(self) -> bool:
        """Whether the voxel features are held in memory (from the second call, when they fit ``hold_mb``)."""
        return self._held is not None

    @property
    def n_blocks(self) -> int:
        return -(-self.n_voxels // self.chunk_rows)

    def block_bounds(self) -> np.ndarray:
        """``(B,2,3)`` int16 first and last ``(row, col, level)`` key of each block (found once by a pass over the
        keys, 64 blocks' at a time, which checks that they ascend: the bounds say nothing of a store whose keys do
        not, and a region would silently miss voxels)."""
        if self._bounds is None:
            bounds = np.zeros((self.n_blocks, 2, 3), np.int16)
            step = 64 * self.chunk_rows
            cols, last = np.int64(self.map.grid.cols), np.int64(-1)
            for s in range(0, self.n_voxels, step):
                key = self.key[s : s + step]
                flat = np.concatenate([[last], (key[:, 0].astype(np.int64) * cols + key[:, 1]) * 65536 + key[:, 2]])
                bad = np.flatnonzero(flat[1:] <= flat[:-1])
                if bad.size:
                    raise ArtifactError(f"{self.map.path}: voxels/key row {s + int(bad[0])} does not come after the "
                                        "row before it (keys ascend by row, column, level in a cfmap zipon writes); "
                                        "rebuild it: zipon run --force --stage cfmap")
                last = flat[-1]
                first = np.arange(0, len(key), self.chunk_rows)
                b = s // self.chunk_rows
                bounds[b : b + len(first), 0] = key[first]
                bounds[b : b + len(first), 1] = key[np.minimum(first + self.chunk_rows, len(key)) - 1]
            self._bounds = bounds
        return self._bounds

    def blocks_in(self, window: Window) -> np.ndarray:
        """``(k,)`` the blocks whose keys can hold a cell of ``window`` (keys ascend by row, then column)."""
        b = self.block_bounds().astype(np.int64)
        ra, ca, rb, cb = b[:, 0, 0], b[:, 0, 1], b[:, 1, 0], b[:, 1, 1]
        r0, r1, c0, c1 = window.r0, window.r1, window.c0, window.c1
        band_a, band_b = (ra >= r0) & (ra < r1), (rb >= r0) & (rb < r1)
        one_row = band_a & (ra == rb) & (ca < c1) & (cb >= c0)  # the block lies in one grid row: cols ca..cb
        first_row = band_a & (ra < rb) & (ca < c1)  # its first row: cols ca..end
        last_row = band_b & (ra < rb) & (cb >= c0)  # its last row: cols 0..cb
        middle = np.maximum(ra + 1, r0) <= np.minimum(rb - 1, r1 - 1)  # whole rows between them
        return np.flatnonzero(one_row | first_row | last_row | middle)

    def _rows(self, k: int) -> tuple[int, int]:
        """Voxel rows ``[s, e)`` of block ``k``."""
        return k * self.chunk_rows, min((k + 1) * self.chunk_rows, self.n_voxels)

    def _hold(self) -> None:
        """Keep the voxel keys and features in memory (as stored, read block by block) when the features' float16
        size fits ``hold_mb``."""
        f = self.features
        if self._held is not None or f.shape[0] * f.shape[1] * 2 > self.hold_mb * 2**20:
            return
        key, feats = np.empty(self.key.shape, self.key.dtype), np.empty(f.shape, f.dtype)
        for s in range(0, self.n_voxels, self.chunk_rows):
            key[s : s + self.chunk_rows] = self.key[s : s + self.chunk_rows]
            feats[s : s + self.chunk_rows] = f[s : s + self.chunk_rows]
        self._held = key, feats

    def _background(self, bg: np.ndarray | None, temp: np.float32) -> tuple[np.ndarray, np.ndarray] | None:
        """Per-voxel background max and logsumexp(/T), ``(M,)`` float32 each, of the held features (for one
        background set at a time: a query leaves out prompts equal to itself); None when the features are not held
        (each block's are then computed in the query's pass) or there are no background prompts."""
        if self._held is None or bg is None:
            return None
        k = bg.tobytes() + np.float64(temp).tobytes()
        if k not in self._bg:
            self._bg = {k: _reduce_background(chunked_scores_each(self._held[1], [bg], self.chunk_rows)[0], temp)}
        return self._bg[k]

    def cell_scores(self, q: np.ndarray, bg: np.ndarray | None, temperature: float, top_s: np.ndarray,
                    top_bg_max: np.ndarray, top_bg_lse: np.ndarray, *, window: Window | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, bg_max, bg_lse)`` float32 per cell, from each cell's best voxel.

        ``q`` ``(D,)`` unit text feature, ``bg`` ``(Tb,D)`` the background prompts in play (the query's own left
        out), ``top_*`` the top-down values, kept for cells without voxels: ``(N,)`` per compact cell row of the
        floor, or with ``window`` ``(n,)`` per observed cell of the window in ascending row order (as
        :class:`~pipeline.maps.query.MapQuery` scores a region); only the voxel blocks that can hold the window's
        cells are read.
        """
        self._calls += 1
        if self._calls == 2:
            self._hold()
        every = whole(self.map.grid)
        window = window or every
        if window == every:
            pos = self.map.index  # (rows, cols): a cell's row of top/* is its place in the outputs
            blocks, n = np.arange(self.n_blocks), self.map.n_cells
        else:
            pos = self.map.index_in(window).astype(np.int64)
            obs = pos >= 0
            pos[obs] = np.searchsorted(np.sort(pos[obs]), pos[obs])  # the cell's place among the window's rows
            blocks, n = self.blocks_in(window), int(obs.sum())
        if len(top_s) != n:
            raise ValueError(f"{self.map.path}: {len(top_s)} top-down scores for the {n} observed cells of {window}")
        best = _Best(n)
        q = np.asarray(q, np.float32)[None]
        bg = np.asarray(bg, np.float32) if bg is not None and bg.shape[0] > 0 else None
        temp = np.float32(temperature)
        cached = self._background(bg, temp)
        for k in blocks:
            start, stop = self._rows(int(k))
            key = self._held[0][start:stop] if self._held is not None else self.key[start:stop]
            r, c = key[:, 0].astype(np.int64), key[:, 1].astype(np.int64)
            inside = window.contains(r, c)
            at = np.full(len(key), -1, np.int64)
            at[inside] = pos[r[inside] - window.r0, c[inside] - window.c0]
            keep = at >= 0  # voxels of the window's observed cells
            if not keep.any():  # the keys tell: its features are not read
                continue
            feats = self._held[1][start:stop] if self._held is not None else self.features[start:stop]
            if bg is None:
                s_v = chunked_scores_each(feats, [q], self.chunk_rows)[0][:, 0]
                bmax_v = blse_v = np.full(len(key), -np.inf, np.float32)
                logit = s_v
            else:
                if cached is None:  # the whole block, so the products have their whole-array shapes
                    s_q, s_bg = chunked_scores_each(feats, [q, bg], self.chunk_rows)
                    bmax_v, blse_v = _reduce_background(s_bg, temp)
                else:
                    s_q = chunked_scores_each(feats, [q], self.chunk_rows)[0]
                    bmax_v, blse_v = cached[0][start:stop], cached[1][start:stop]
                s_v = s_q[:, 0]
                logit = s_v / temp - blse_v
            best.update(at[keep], logit[keep], s_v[keep], bmax_v[keep], blse_v[keep])
        s, bm, bl = (np.array(a, dtype=np.float32, copy=True) for a in (top_s, top_bg_max, top_bg_lse))
        has = best.has
        s[has], bm[has], bl[has] = best.s[has], best.bg_max[has], best.bg_lse[has]
        return s, bm, bl


def _reduce_background(scores: np.ndarray, temp: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """``(max, logsumexp(/T))`` ``(m,)`` float32 of background scores ``(m,Tb)``."""
    return scores.max(axis=1), logsumexp(scores / temp, axis=1).astype(np.float32)


class _Best:
    """Per cell the best voxel seen so far: its logit and its three values; blocks come in voxel order."""

    def __init__(self, n: int):
        self.has = np.zeros(n, bool)
        self.logit, self.s, self.bg_max, self.bg_lse = (np.full(n, np.nan, np.float32) for _ in range(4))

    def update(self, cell: np.ndarray, logit: np.ndarray, s: np.ndarray, bg_max: np.ndarray, bg_lse: np.ndarray
               ) -> None:
        """Fold in one block's voxels (``cell`` their output place, in voxel order): per cell the voxel of the
        highest logit, the earliest on ties and NaN last (numpy's sort order: the whole array's ``lexsort``), then
        kept only where it beats the cell's voxel from an earlier block."""
        order = np.lexsort((np.arange(len(cell)), -logit, cell))
        first = np.r_[True, cell[order][1:] != cell[order][:-1]]
        pick = order[first]
        c, new = cell[pick], logit[pick]
        old = self.logit[c]
        take = ~self.has[c] | (new > old) | (np.isnan(old) & ~np.isnan(new))
        c, pick = c[take], pick[take]
        self.has[c] = True
        self.logit[c], self.s[c], self.bg_max[c], self.bg_lse[c] = logit[pick], s[pick], bg_max[pick], bg_lse[pick]
