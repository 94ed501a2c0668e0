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
``maps.fill_radius_m``) keep their top-down values. Voxel features stay float16 in memory and
are upcast per chunk of ``chunk_rows``; background scores are cached per background set.

Used by :class:`~pipeline.maps.query.MapQuery` when ``query.levels`` is ``max`` and the map stores
voxels (``top``, the default, scores the top-down features only). Everything is numpy: a query on a
map needs no torch.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import ArtifactError
from pipeline.maps.scoring import chunked_scores, logsumexp
from pipeline.maps.store import SemanticMap


class LevelScorer:
    """Best-level scores of a map's voxels per cell (see the module docstring)."""

    def __init__(self, smap: SemanticMap, *, chunk_rows: int = 4096):
        vx = smap.voxels()
        if vx is None:
            raise ArtifactError(f"{smap.path}: no voxels/ group; level-aware queries (query.levels: max) need a "
                                f"cfmap built with maps.cfmap_voxels: true (rebuild: zipon run --force --stage cfmap)")
        key = vx.key.astype(np.int64)
        row = smap.index[key[:, 0], key[:, 1]].astype(np.int64)  # compact row of the voxel's cell
        ok = row >= 0
        self.n_cells = smap.n_cells
        self.row = row[ok]
        self.feats = np.ascontiguousarray(vx.features[ok])  # (M,D) float16
        self.chunk_rows = chunk_rows
        self._bg: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def n_voxels(self) -> int:
        return int(self.row.shape[0])

    def _background(self, bg: np.ndarray | None, temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """Per-voxel background max and logsumexp(/T), ``(M,)`` each; -inf without background prompts."""
        if bg is None or bg.shape[0] == 0:
            inf = np.full(self.n_voxels, -np.inf, np.float32)
            return inf, inf
        k = np.asarray(bg, np.float32).tobytes() + np.float64(temperature).tobytes()
        if k not in self._bg:  # one background set at a time (a query leaves out prompts equal to itself)
            s = chunked_scores(self.feats, bg, self.chunk_rows)
            self._bg = {k: (s.max(axis=1), logsumexp(s / np.float32(temperature), axis=1).astype(np.float32))}
        return self._bg[k]

    def cell_scores(self, q: np.ndarray, bg: np.ndarray | None, temperature: float, top_s: np.ndarray,
                    top_bg_max: np.ndarray, top_bg_lse: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, bg_max, bg_lse)`` ``(N,)`` float32 per compact cell row, from each cell's best voxel.

        ``q`` ``(D,)`` unit text feature, ``bg`` ``(Tb,D)`` the background prompts in play (the query's
        own left out), ``top_*`` the top-down values, kept for cells without voxels.
        """
        s_v = chunked_scores(self.feats, np.asarray(q, np.float32)[None], self.chunk_rows)[:, 0]
        bmax_v, blse_v = self._background(bg, temperature)
        logit = s_v / np.float32(temperature) - blse_v if bg is not None and bg.shape[0] else s_v
        # per cell the voxel of the highest logit, the lowest voxel (the lowest level) on ties
        order = np.lexsort((np.arange(self.n_voxels), -logit, self.row))
        first = np.r_[True, self.row[order][1:] != self.row[order][:-1]] if self.n_voxels else np.zeros(0, bool)
        pick = order[first]
        rows = self.row[pick]
        s, bm, bl = (np.array(a, dtype=np.float32, copy=True) for a in (top_s, top_bg_max, top_bg_lse))
        s[rows], bm[rows], bl[rows] = s_v[pick], bmax_v[pick], blse_v[pick]
        return s, bm, bl
