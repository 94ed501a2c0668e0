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

Hook (query.py): build ``LevelScorer(smap)`` once when ``smap.has_voxels`` and
``params.query_levels == "max"``; in ``MapQuery.query`` after the top-down ``s, bg_max, bg_lse`` are
known: ``s, bg_max, bg_lse = scorer.cell_scores(q, bg_feats_kept, T, s, bg_max, bg_lse)``.
"""

from __future__ import annotations

import numpy as np
import torch

from pipeline.errors import ArtifactError
from pipeline.maps.scoring import chunked_scores
from pipeline.maps.store import SemanticMap


class LevelScorer:
    """Best-level scores of a map's voxels per cell (see the module docstring)."""

    def __init__(self, smap: SemanticMap, *, chunk_rows: int = 65536):
        vx = smap.voxels()
        if vx is None:
            raise ArtifactError(f"{smap.path}: no voxels/ group; level-aware queries need a cfmap built with "
                                f"maps.cfmap_voxels: true (rebuild: zipon run --force --stage cfmap)")
        key = vx["key"].astype(np.int64)
        row = smap.index[key[:, 0], key[:, 1]].astype(np.int64)  # compact row of the voxel's cell
        ok = row >= 0
        self.n_cells = smap.n_cells
        self.row = torch.from_numpy(row[ok])
        self.feats = torch.from_numpy(np.ascontiguousarray(vx["features"][ok]))  # (M,D) float16
        self.chunk_rows = chunk_rows
        self._bg: dict[bytes, tuple[torch.Tensor, torch.Tensor, float]] = {}

    @property
    def n_voxels(self) -> int:
        return int(self.row.shape[0])

    def _background(self, bg: torch.Tensor | None, temperature: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-voxel background max and logsumexp(/T), ``(M,)`` each; -inf without background prompts."""
        if bg is None or bg.shape[0] == 0:
            inf = torch.full((self.n_voxels,), -torch.inf)
            return inf, inf
        k = bg.to(torch.float32).numpy().tobytes() + np.float64(temperature).tobytes()
        if k not in self._bg:
            s = chunked_scores(self.feats, bg, self.chunk_rows)
            self._bg = {k: (s.max(dim=1).values, torch.logsumexp(s / temperature, dim=1), temperature)}
        bmax, blse, _ = self._bg[k]
        return bmax, blse

    def cell_scores(self, q: torch.Tensor, bg: torch.Tensor | None, temperature: float, top_s: np.ndarray,
                    top_bg_max: np.ndarray, top_bg_lse: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, bg_max, bg_lse)`` ``(N,)`` float32 per compact cell row, from each cell's best voxel.

        ``q`` ``(D,)`` unit text feature, ``bg`` ``(Tb,D)`` the background prompts in play (the query's
        own left out), ``top_*`` the top-down values, kept for cells without voxels.
        """
        s_v = chunked_scores(self.feats, q[None], self.chunk_rows)[:, 0]
        bmax_v, blse_v = self._background(bg, temperature)
        logit = s_v / temperature - blse_v if bg is not None and bg.shape[0] else s_v
        best = torch.full((self.n_cells,), -torch.inf).scatter_reduce_(0, self.row, logit, "amax")
        hit = logit == best[self.row]
        vid = torch.arange(self.n_voxels)
        pick = torch.full((self.n_cells,), self.n_voxels, dtype=torch.int64).scatter_reduce_(
            0, self.row[hit], vid[hit], "amin")
        has = pick < self.n_voxels
        s, bm, bl = (np.array(a, dtype=np.float32, copy=True) for a in (top_s, top_bg_max, top_bg_lse))
        rows, v = torch.nonzero(has).squeeze(1).numpy(), pick[has]
        s[rows], bm[rows], bl[rows] = s_v[v].numpy(), bmax_v[v].numpy(), blse_v[v].numpy()
        return s, bm, bl
