"""Text queries on a semantic map: a similarity heatmap and object candidates (like navchat's retrieve_map).

Scoring (VLMaps' background handling): a cell's score for a prompt is the dot product of its
unit feature with the prompt's unit text feature. The query competes with the background prompts
of ``query.background`` (default 'other', 'floor', 'wall', 'ceiling'; a background prompt whose
text feature is the query's own, cosine > 0.99, is left out):

- heatmap = softmax probability of the query among [query, background...] with temperature
  ``query.temperature`` (else the encoder's, else 0.1) — ``sigmoid(s_q / T - logsumexp(s_bg / T))``;
  NaN where the map has no feature;
- a cell WINS when the query's score beats every background score (VLMaps' argmax rule) AND its
  probability is at least ``query.min_probability`` (default 0.5: the query outweighs all background
  prompts together). The second condition stops cells of OTHER objects, which score about as low
  on the query as on the background and so win the argmax by chance, from joining a real object's
  component;
- candidates are the 8-connected components of winning cells of at least
  ``query.min_candidate_area_m2`` and mean probability ``query.min_candidate_score``, found with
  opencv. Each has an ``obj_id`` (its rank in this
  result, 1-based), a ``center_xy`` (the component's cell nearest its centroid, so it always lies on
  the component), the cell nearest the pose, the navigable cell nearest the centre (an
  approach point, when recon's navigable grid is given; of equally near ones the first in
  row-major order), ``distance_m`` from the pose to the nearest cell and ``angle_rad`` = bearing
  of the centre relative to the pose's heading (counter-clockwise positive, so > 0 means to the left), ``area_m2`` and ``score`` (mean
  heatmap probability). With a pose, candidates are sorted by distance (retrieve_map's order);
  without one, by mass = score x area, largest first.

Levels (``query.levels``): ``top`` scores each cell by its top-down feature (its highest height
level); ``max`` scores each cell of a cfmap that stores voxels by its best level for the query
(:class:`~pipeline.maps.levels.LevelScorer`), so a chair under a table top or a picture on a wall
wins cells the top-down view gives to the table or the wall; its voxels are read block by block (with a region,
only the blocks that can hold its cells), so memory stays a block plus a few values per cell. A vlmap has one level
per cell.

Tiles and memory: the map's features are read one stored chunk at a time (whole spatial tiles' rows,
:meth:`~pipeline.maps.store.SemanticMap.blocks`), each upcast and scored, so a query holds one chunk's features
plus a few float32 scores per observed cell, never the map's ``(N,D)`` features. The background scores are computed
once per :class:`MapQuery` (with the first query's, in the same pass), text features are cached per prompt. From
the second query on, a map whose fp16 features fit ``query.hold_features_mb`` is held as one fp32 copy (read tile
by tile), so a repeated query costs one ``(N,D) @ (D,)`` product (or the low-rank one) plus the connected
components; a larger map is read tile by tile for every query. A ``region`` (world metres,
:mod:`pipeline.region`) scores only the cells in it, reading only the tiles it meets; the result's grid is then
the region's window (its heatmap, masks and candidates' cells are on that grid; world metres are unchanged).
Every path gives the same scores: float32 products of the stored fp16 features. Scoring is numpy: with an encoder
whose text side needs no torch (the oracle, :func:`pipeline.encoders.text.text_encoder`) a query never imports
torch.
"""

from __future__ import annotations

import math
from collections import OrderedDict
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import ArtifactError, LineageError
from pipeline.geometry import GridSpec
from pipeline.maps.scoring import chunked_scores, logsumexp
from pipeline.maps.store import SemanticMap
from pipeline.region import Region, Window, region_window, whole

DEFAULT_TEMPERATURE = 0.1


@dataclass
class Candidate:
    """One object candidate (world metres, radians)."""

    obj_id: int
    center_xy: tuple[float, float]
    centroid_xy: tuple[float, float]
    nearest_xy: tuple[float, float]
    approach_xy: tuple[float, float] | None
    distance_m: float | None
    angle_rad: float | None
    area_m2: float
    score: float
    center_rc: tuple[int, int]
    bbox_rc: tuple[int, int, int, int]  # row0, col0, row1 (excl), col1 (excl)
    label: int = 0  # component label in ``QueryResult.labels``
    gt_instance: int | None = None  # ground-truth instance under the centre (0 = none), when GT is given
    gt_class: str | None = None
    floor: int = 0  # index of the floor (lowest first) whose map holds it


@dataclass
class QueryResult:
    """Heatmap ``(rows, cols)`` float32 (NaN unobserved), winning mask ``(rows, cols)`` bool, candidates."""

    text: str
    artifact: str
    grid: GridSpec
    heatmap: np.ndarray
    wins: np.ndarray
    candidates: list[Candidate]
    pose: tuple[float, float, float] | None
    background: list[str]
    temperature: float
    seconds: float
    levels: str = "top"  # how cells were scored: top-down features, or each cell's best height level
    labels: np.ndarray | None = field(default=None, repr=False)  # (rows, cols) int32 component labels
    color: np.ndarray | None = field(default=None, repr=False)  # (rows, cols, 3) uint8 recon colour, if known
    floor: int = 0  # index of the floor queried (lowest first; 0 for a single-floor scene)
    floor_name: str = "floor 0"
    region: Region | None = None  # the region queried (world metres; ``grid`` is then its window), None = the floor

    def to_json(self) -> dict:
        """JSON-able summary (no arrays): the query, the floor, the pose and every candidate."""
        observed = np.isfinite(self.heatmap)
        return {
            "text": self.text,
            "map": self.artifact,
            "floor": self.floor,
            "floor_name": self.floor_name,
            "region": None if self.region is None else asdict(self.region),
            "pose": None if self.pose is None else list(self.pose),
            "background": self.background,
            "temperature": self.temperature,
            "levels": self.levels,
            "cells_observed": int(observed.sum()),
            "cells_winning": int(self.wins.sum()),
            "seconds": round(self.seconds, 5),
            "candidates": [asdict(c) for c in self.candidates],
        }


class MapQuery:
    """Queries on one map with one encoder (text side). Cheap to query repeatedly; see the module docstring.

    ``encoder``: anything with ``name``, ``dim``, ``identity()`` and ``encode_text(texts)`` giving ``(T,D)`` unit
    rows (an :class:`~pipeline.encoders.base.Encoder`, or a torch-free
    :class:`~pipeline.encoders.text.TextEncoder`). ``params``: the ``query`` section. ``navigable``
    ``(rows, cols)`` bool (recon) gives approach points; ``gt`` (a GTScene) labels candidates with the
    ground-truth instance under them.
    """

    def __init__(self, smap: SemanticMap, encoder, params, *, navigable: np.ndarray | None = None, gt=None,
                 color: np.ndarray | None = None, recon_floor=None):
        self.map, self.encoder, self.params, self.color = smap, encoder, params, color
        self.recon_floor = recon_floor  # recon's FloorGrids: the colour of each queried window, read when asked
        ident = smap.encoder
        if ident.get("name") != encoder.name or int(ident.get("dim", -1)) != encoder.dim:
            raise ArtifactError(
                f"{smap.path}: map built with encoder {ident.get('name')!r} (dim {ident.get('dim')}), "
                f"query encoder is {encoder.name!r} (dim {encoder.dim}); query with the map's encoder"
            )
        for key in ("version", "weights_digest"):
            if key in ident and ident[key] != encoder.identity().get(key):
                raise ArtifactError(f"{smap.path}: encoder {key} {ident[key]!r} differs from the query encoder's "
                                    f"{encoder.identity().get(key)!r}")
        self.grid = smap.grid
        self.temperature = float(params.temperature or ident.get("temperature") or DEFAULT_TEMPERATURE)
        self.background = list(params.background)
        self.levels = params.levels if smap.has_voxels else "top"  # a map without voxels has one level per cell
        self._levels = None  # the LevelScorer, built on the first query that needs it
        self._text: dict[str, np.ndarray] = {}
        self._f32: np.ndarray | None = None  # (N,D) fp32, held from the second query when it fits (module doc)
        self._n_queries = 0
        self._bg_feats = self.text_features(self.background) if self.background else None
        self._bg_scores: np.ndarray | None = None  # (N,Tb), computed with the first query
        self._bg_cache: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
        self._lowrank: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._nav_rc: np.ndarray | None = None  # (M,2) navigable cells, row-major
        if navigable is not None:
            if navigable.shape != (self.grid.rows, self.grid.cols):
                raise LineageError(f"{smap.path}: navigable grid {navigable.shape} does not match the map's grid "
                                   f"{(self.grid.rows, self.grid.cols)} (map and recon from different runs?)")
            if navigable.any():
                self._nav_rc = np.argwhere(navigable).astype(np.int32)
        self.gt = gt
        self._footprints = gt.instance_footprints(self.grid) if gt is not None else None

    def _nearest_navigable(self, rc: tuple[int, int]) -> np.ndarray:
        """The navigable cell nearest ``rc`` (Euclidean, in cells; ties to the first in row-major order): one
        distance per navigable cell per candidate, instead of a distance transform of the whole grid per map."""
        d2 = (self._nav_rc[:, 0] - rc[0]).astype(np.int64) ** 2 + (self._nav_rc[:, 1] - rc[1]).astype(np.int64) ** 2
        return self._nav_rc[int(np.argmin(d2))]

    # ------------------------------------------------------------------ text
    def text_features(self, texts: list[str]) -> np.ndarray:
        """``(T,D)`` float32 unit text features (cached per prompt; prompts not seen yet are encoded in one call)."""
        missing = [t for t in dict.fromkeys(texts) if t not in self._text]
        if missing:
            for t, f in zip(missing, np.asarray(self.encoder.encode_text(missing), dtype=np.float32)):
                self._text[t] = f
        return np.stack([self._text[t] for t in texts])

    def _background_for(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """Per-cell max and logsumexp(/T) of the background scores, leaving out prompts equal to ``q``."""
        if self._bg_feats is None:
            n = len(self.map.cell)
            return np.full(n, -np.inf, np.float32), np.full(n, -np.inf, np.float32), []
        keep = tuple(int(i) for i in np.flatnonzero(self._bg_feats @ q <= 0.99))
        if keep not in self._bg_cache:
            if not keep:
                n = len(self.map.cell)
                self._bg_cache[keep] = (np.full(n, -np.inf, np.float32), np.full(n, -np.inf, np.float32))
            else:
                s = self._bg_scores[:, list(keep)]
                self._bg_cache[keep] = (s.max(axis=1), logsumexp(s / np.float32(self.temperature), axis=1))
        bg_max, bg_lse = self._bg_cache[keep]
        return bg_max, bg_lse, list(keep)

    # ------------------------------------------------------------------ scores
    def _product(self, text: np.ndarray) -> np.ndarray:
        """``(N,T)`` float32 scores of every cell against ``text`` ``(T,D)``: of the held features, else read block by
        block (:meth:`~pipeline.maps.store.SemanticMap.blocks`)."""
        if self._f32 is not None:
            return self._f32 @ text.T
        out = np.empty((self.map.n_cells, len(text)), np.float32)
        for rows, _, feats in self.map.blocks():
            out[rows[0]:rows[-1] + 1] = chunked_scores(feats, text)  # a whole-floor block's rows are contiguous
        return out

    def _window_product(self, window: Window, text: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows ``(n,)`` and flat cells ``(n,)`` of the observed cells in ``window`` and their ``(n,T)`` float32
        scores against ``text``, reading only the tiles the window meets."""
        rows, cells, scores = [], [], []
        if self._f32 is not None:  # held: the rows of the window's tiles, no read
            r = np.concatenate([np.arange(s, e) for s, e in self.map.row_ranges(window)] or [np.zeros(0, np.int64)])
            r = r[window.contains(*np.divmod(self.map.cell[r], self.grid.cols))]
            return r, self.map.cell[r], self._f32[r] @ text.T
        for r, c, feats in self.map.blocks(window):
            rows.append(r)
            cells.append(c)
            scores.append(chunked_scores(feats, text))
        if not rows:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, len(text)), np.float32)
        return np.concatenate(rows), np.concatenate(cells), np.concatenate(scores)

    def _hold(self) -> None:
        """Keep the map's features as one fp32 copy (read block by block) when their fp16 size fits
        ``query.hold_features_mb``."""
        n, dim = self.map.n_cells, self.map.dim
        if self._f32 is not None or n * dim * 2 > self.params.hold_features_mb * 2**20:
            return
        f32 = np.empty((n, dim), np.float32)
        for rows, _, feats in self.map.blocks():
            f32[rows[0]:rows[-1] + 1] = feats
        self._f32 = f32

    def _rows(self, idx: np.ndarray) -> np.ndarray:
        """``(len(idx),D)`` float32 features of the held cells ``idx``."""
        return self._f32[idx]

    def _basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rank-k basis V ``(D,k)`` of the held map features, projections ``(N,k)`` and residual norms ``(N,)``."""
        if self._lowrank is None:
            n = len(self._f32)
            sample = self._rows(np.linspace(0, n - 1, min(n, 20_000)).astype(np.int64))
            _, _, vh = np.linalg.svd(sample, full_matrices=False)
            V = np.ascontiguousarray(vh[: self.params.query_rank].T)
            P = self._product(V.T)
            resid = np.sqrt(np.clip(1.0 - (P * P).sum(axis=1), 0, None))  # rows of F are unit: |F - P V^T|^2 = 1 - |P|^2
            self._lowrank = (V, P, resid)
        return self._lowrank

    def _scores(self, q: np.ndarray, bg_max: np.ndarray, bg_lse: np.ndarray, exact: np.ndarray | None = None
                ) -> np.ndarray:
        """``(N,)`` query scores: exact, or (large maps) low-rank with exact refinement where it matters.

        Low rank: ``s~ = (F V)(V^T q)`` with ``|s - s~| <= r_i |q_perp|`` (``r_i`` the residual norm of
        row i). Every cell whose upper bound ``s~ + bound`` could win (beat the background and reach
        ``min_probability``) is recomputed exactly, so the winning cells, the candidates and the heatmap
        of every cell that can win are exact; other cells keep ``s~`` (their probability stays below
        ``min_probability``, within the bound). ``exact``: the exact scores when already computed.
        """
        if exact is not None:
            return exact
        n, dim = self.map.n_cells, self.map.dim
        if (self._f32 is None or self.params.query_rank == 0 or n < self.params.query_lowrank_min_cells
                or self.params.query_rank >= dim):
            return self._product(q[None])[:, 0]
        V, P, resid = self._basis()
        ql = V.T @ q
        q_perp = float((1.0 - float(ql @ ql)) if float(ql @ ql) < 1.0 else 0.0) ** 0.5
        s = P @ ql
        upper = s + resid * q_perp
        p_upper = 1.0 / (1.0 + np.exp(np.clip(bg_lse - upper / self.temperature, -80, 80)))
        idx = np.flatnonzero((upper > bg_max) & (p_upper >= self.params.min_probability))
        if len(idx):
            s[idx] = self._rows(idx) @ q
        return s

    # ------------------------------------------------------------------ query
    def scores(self, text: str) -> np.ndarray:
        """``(N,)`` float32 dot products of the observed cells with ``text``."""
        q = self.text_features([text])[0]
        return self._product(q[None])[:, 0]

    def query(self, text: str, pose: tuple[float, float, float] | None = None, *, region: Region | None = None
              ) -> QueryResult:
        """Heatmap and candidates for ``text``; ``pose`` = (x, y, yaw) world metres / radians; ``region`` (world
        metres) scores only its cells (an InputDataError naming ``region`` when it misses the grid)."""
        t0 = time.perf_counter()
        q = self.text_features([text])[0]
        window = region_window(self.grid, region, "region")
        if window == whole(self.grid):
            self._n_queries += 1
            if self._n_queries == 2:  # queried again: hold the features when they fit (module doc)
                self._hold()
            rows, cells = None, self.map.cell  # (N,) int64, read once (then each block's cells come from it)
            s, bg_max, bg_lse, keep = self._floor_scores(q)
        else:
            rows, cells, s, bg_max, bg_lse, keep = self._region_scores(q, window)
        if self.levels == "max":
            s, bg_max, bg_lse = self._level_scores(q, keep, s, bg_max, bg_lse, None if rows is None else window)
        prob = 1.0 / (1.0 + np.exp(np.clip(bg_lse - s / self.temperature, -80, 80)))
        g = window.grid(self.grid)
        r, c = np.divmod(cells, self.grid.cols)
        local = (r - window.r0) * g.cols + (c - window.c0)  # flat cells of the window's grid
        heat = np.full(g.rows * g.cols, np.nan, np.float32)
        heat[local] = prob
        wins_flat = np.zeros(g.rows * g.cols, np.uint8)
        wins_flat[local[(s > bg_max) & (prob >= self.params.min_probability)]] = 1
        heat, wins = heat.reshape(g.rows, g.cols), wins_flat.reshape(g.rows, g.cols)
        box = self._observed_box() if rows is None else _box(r - window.r0, c - window.c0)
        cands, labels = self._candidates(wins, heat, pose, window, box)
        return QueryResult(text=text, artifact=self.map.artifact, grid=g, heatmap=heat, wins=wins.astype(bool),
                           candidates=cands, pose=None if pose is None else tuple(float(v) for v in pose),
                           background=[self.background[i] for i in keep], temperature=self.temperature,
                           seconds=time.perf_counter() - t0, levels=self.levels, labels=labels,
                           color=self._color(window), floor=self.map.floor_index, floor_name=self.map.floor.name,
                           region=region)

    def _floor_scores(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
        """``(s, bg_max, bg_lse)`` ``(N,)`` of every observed cell and the background prompts in play."""
        exact = None
        if self._bg_feats is not None and self._bg_scores is None:  # the first query: background and query in one pass
            both = self._product(np.concatenate([self._bg_feats, q[None]]))
            self._bg_scores, exact = both[:, :-1], both[:, -1]
        bg_max, bg_lse, keep = self._background_for(q)
        return self._scores(q, bg_max, bg_lse, exact), bg_max, bg_lse, keep

    def _region_scores(self, q: np.ndarray, window: Window):
        """Rows, flat cells and ``(s, bg_max, bg_lse)`` of the observed cells in ``window`` (its tiles only), and
        the background prompts in play."""
        keep = [] if self._bg_feats is None else [int(i) for i in np.flatnonzero(self._bg_feats @ q <= 0.99)]
        text = np.concatenate([self._bg_feats[keep], q[None]]) if keep else q[None]
        rows, cells, both = self._window_product(window, text)
        if keep:
            bg = both[:, :-1]
            bg_max, bg_lse = bg.max(axis=1), logsumexp(bg / np.float32(self.temperature), axis=1)
        else:
            bg_max = bg_lse = np.full(len(rows), -np.inf, np.float32)
        return rows, cells, both[:, -1], bg_max, bg_lse, keep

    def _level_scores(self, q, keep, s, bg_max, bg_lse, window: Window | None):
        """The cells' scores from their best height level (:class:`~pipeline.maps.levels.LevelScorer`, reading the
        voxels block by block); ``window``: the region whose observed cells ``s`` etc. hold, in row order (its voxel
        blocks only), None: every row of the floor."""
        bg = self._bg_feats[keep] if keep else None
        return self._level_scorer().cell_scores(q, bg, self.temperature, s, bg_max, bg_lse, window=window)

    def _color(self, window: Window) -> np.ndarray | None:
        """``(rows, cols, 3)`` uint8 recon colour of ``window`` (read from recon's tiles when given so)."""
        if self.color is not None:
            return self.color[window.slices]
        if self.recon_floor is None:
            return None
        if window != whole(self.grid):
            return self.recon_floor.window(window).color
        if "_floor_color" not in self.__dict__:  # the whole floor's, read once
            self.__dict__["_floor_color"] = self.recon_floor.color
        return self.__dict__["_floor_color"]

    def _level_scorer(self):
        """The map's :class:`~pipeline.maps.levels.LevelScorer` (voxel features read block by block at each query;
        held from the second query on when they fit ``query.hold_features_mb``)."""
        if self._levels is None:
            from pipeline.maps.levels import LevelScorer

            self._levels = LevelScorer(self.map, hold_mb=self.params.hold_features_mb)
        return self._levels

    def _observed_box(self) -> tuple[int, int, int, int]:
        """``(r0, r1, c0, c1)`` bounding box (end exclusive) of the map's observed cells (cached)."""
        box = self.__dict__.get("_obs_box")
        if box is None:
            box = self.__dict__["_obs_box"] = _box(*np.divmod(np.asarray(self.map.cell), self.grid.cols))
        return box

    def _candidates(self, wins: np.ndarray, heat: np.ndarray, pose, window: Window,
                    box: tuple[int, int, int, int]) -> tuple[list[Candidate], np.ndarray]:
        """Candidates on the window's grid (``wins``, ``heat`` its shape; ``box`` its observed cells)."""
        g = window.grid(self.grid)
        # components only where the map has observed cells (wins are 0 elsewhere): work on that bounding box
        r0, r1, c0, c1 = box
        n, sub, stats, centroids = cv2.connectedComponentsWithStats(np.ascontiguousarray(wins[r0:r1, c0:c1]),
                                                                    connectivity=8, ltype=cv2.CV_32S)
        stats[:, cv2.CC_STAT_LEFT] += c0
        stats[:, cv2.CC_STAT_TOP] += r0
        centroids = centroids + np.array([c0, r0], np.float64)
        labels = np.zeros(wins.shape, np.int32)
        labels[r0:r1, c0:c1] = sub
        min_cells = max(1, math.ceil(self.params.min_candidate_area_m2 / g.cell_size_m**2 - 1e-9))
        area = stats[:, cv2.CC_STAT_AREA]
        rr, cc = np.nonzero(sub)
        rr, cc = rr + r0, cc + c0
        lab = labels[rr, cc]
        score = np.bincount(lab, weights=heat[rr, cc], minlength=n) / np.maximum(area, 1)
        ok = (area >= min_cells) & (score >= self.params.min_candidate_score)
        ok[0] = False
        sel = ok[lab]
        rr, cc, lab = rr[sel], cc[sel], lab[sel]
        if not len(lab):
            return [], np.zeros_like(labels)
        # centre: the component's cell nearest its centroid (centroids are (x=col, y=row))
        d_c = (cc - centroids[lab, 0]) ** 2 + (rr - centroids[lab, 1]) ** 2
        centre = _first_per_label(lab, d_c)
        if pose is not None:
            prc = np.array([(g.origin_xy[1] - pose[1]) / g.cell_size_m - 0.5, (pose[0] - g.origin_xy[0]) / g.cell_size_m - 0.5])
            near = _first_per_label(lab, (rr - prc[0]) ** 2 + (cc - prc[1]) ** 2)
        else:
            near = centre
        ids = np.flatnonzero(ok)
        # order (vectorized) before building at most max_candidates records
        if pose is not None:
            nxy_all = g.cell_to_world(np.stack([rr[near[ids]], cc[near[ids]]], axis=1))
            d_all = np.hypot(nxy_all[:, 0] - pose[0], nxy_all[:, 1] - pose[1])
            rank = np.lexsort((-score[ids], d_all))
        else:
            rank = np.lexsort((cc[centre[ids]], rr[centre[ids]], -score[ids] * area[ids]))
        ids = ids[rank[: self.params.max_candidates]]
        out = []
        for k in ids:
            crc = (int(rr[centre[k]]), int(cc[centre[k]]))
            nrc = (int(rr[near[k]]), int(cc[near[k]]))
            cxy = tuple(float(v) for v in g.cell_to_world(np.array(crc)))
            nxy = tuple(float(v) for v in g.cell_to_world(np.array(nrc)))
            gxy = g.cell_to_world(np.array([centroids[k, 1], centroids[k, 0]]))
            approach = None
            full = (crc[0] + window.r0, crc[1] + window.c0)  # the cell in the floor's grid
            if self._nav_rc is not None:
                approach = tuple(float(v) for v in self.grid.cell_to_world(self._nearest_navigable(full)))
            dist = ang = None
            if pose is not None:
                dist = float(math.hypot(nxy[0] - pose[0], nxy[1] - pose[1]))
                ang = float(_wrap(math.atan2(cxy[1] - pose[1], cxy[0] - pose[0]) - pose[2]))
            x, y, w, h = (int(v) for v in stats[k, :4])
            gt_id = gt_cls = None
            if self._footprints is not None:
                gt_id = int(self._footprints[full])
                gt_cls = self.gt.object(gt_id).cls if gt_id else None
            out.append(Candidate(obj_id=0, center_xy=cxy, centroid_xy=(float(gxy[0]), float(gxy[1])), nearest_xy=nxy,
                                 approach_xy=approach, distance_m=dist, angle_rad=ang,
                                 area_m2=float(area[k] * g.cell_size_m**2), score=float(score[k]), center_rc=crc,
                                 bbox_rc=(y, x, y + h, x + w), label=int(k), gt_instance=gt_id, gt_class=gt_cls,
                                 floor=self.map.floor_index))
        for i, c in enumerate(out, 1):
            c.obj_id = i
        return out, labels


def _box(row: np.ndarray, col: np.ndarray) -> tuple[int, int, int, int]:
    """``(r0, r1, c0, c1)`` bounding box (end exclusive) of cells ``(row, col)``; a one-cell box when there are
    none (no wins anywhere)."""
    if not len(row):
        return 0, 1, 0, 1
    return int(row.min()), int(row.max()) + 1, int(col.min()), int(col.max()) + 1


def _first_per_label(lab: np.ndarray, key: np.ndarray) -> np.ndarray:
    """``(n_labels,)`` index into ``lab`` of the element with the smallest ``key`` per label (-1 if absent)."""
    order = np.lexsort((key, lab))
    first = np.r_[True, lab[order][1:] != lab[order][:-1]]
    out = np.full(int(lab.max()) + 1, -1, np.int64)
    out[lab[order][first]] = order[first]
    return out


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


# ----------------------------------------------------------------------------- API for the CLI / evaluator

#: the open queries, least recently used first; at most :data:`CACHE_SIZE` are kept (each may hold its map's features,
#: ``query.hold_features_mb``, so a long-lived process that queries many scenes, the workbench's server or an
#: evaluation's report drawing each scene's queries, would otherwise keep every map it ever opened)
_CACHE: OrderedDict[tuple, MapQuery] = OrderedDict()
CACHE_SIZE = 8  # a scene's two maps on up to four floors


def open_query(map_path: str | Path, params, *, recon_path: str | Path | None = None,
               frames_path: str | Path | None = None, floor: int = 0) -> MapQuery:
    """A cached :class:`MapQuery` (the :data:`CACHE_SIZE` most recently used are kept) for floor ``floor`` of a map
    store (``params`` = the whole :class:`~pipeline.config.Params`; ``floor`` an index, lowest first, 0 for a
    single-floor scene).

    The text encoder is built from ``params.encoders`` by the NAME recorded in the map (so it always
    matches the map's feature space; a different version or weights file is an ArtifactError): its
    torch-free text side when it has one (:func:`pipeline.encoders.text.text_encoder`), else the whole
    encoder. ``frames_path`` gives the scene's ground truth (needed by the oracle encoder, and labels
    candidates with GT instances of that floor); ``recon_path`` gives the floor's navigable approach points and
    colour and checks lineage.
    """
    from pipeline.encoders.text import text_encoder
    from pipeline.frames import FrameStore

    key = (str(map_path), str(recon_path), str(frames_path), id(params), floor)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    smap = SemanticMap(map_path, floor)
    navigable = recon_floor = None
    if recon_path is not None:
        from pipeline.recon import Recon

        recon = Recon(recon_path)
        if len(recon.floors) != len(smap.floors):
            raise LineageError(f"{map_path}: {len(smap.floors)} floors but {recon_path} has {len(recon.floors)}; "
                               "rebuild the map")
        grids = recon.floor(floor)
        if grids.grid != smap.grid:
            raise LineageError(f"{map_path}: grid {smap.grid} differs from {recon_path}'s {grids.grid}"
                               f"{f' (floor {floor})' if floor else ''}; rebuild the map")
        navigable, recon_floor = grids.navigable, grids
    gt = None
    if frames_path is not None and Path(frames_path).exists():
        gt = FrameStore(frames_path).ground_truth
    encoder = text_encoder(params.encoders, smap.encoder["name"])
    if encoder is None:
        from pipeline.encoders import build_encoder

        encoder = build_encoder(params.encoders, smap.encoder["name"], runtime=params.run)
    encoder.bind_scene(gt)
    mq = MapQuery(smap, encoder, params.query, navigable=navigable, gt=None if gt is None else gt_floor(gt, smap.floor),
                  recon_floor=recon_floor)
    _CACHE[key] = mq
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return mq


def gt_floor(gt, floor):
    """The ground truth of the floor ``floor`` (a :class:`~pipeline.recon.store.Floor` found by reconstruct) as a
    single-floor :class:`~pipeline.scene_gt.GTScene`: the true floor nearest its height (the scene itself when it
    has one floor)."""
    floors = gt.all_floors
    if len(floors) == 1:
        return gt
    nearest = min(range(len(floors)), key=lambda k: abs(floors[k].floor_z - floor.floor_z_m))
    return gt.floor_view(nearest)


def query_map(map_path: str | Path, recon_path: str | Path | None, text: str,
              pose: tuple[float, float, float] | None = None, *, params, frames_path: str | Path | None = None,
              floor: int = 0) -> QueryResult:
    """One query of one floor: heatmap + candidates; see :class:`MapQuery` (every floor:
    :func:`pipeline.maps.floors.query_floors`)."""
    return open_query(map_path, params, recon_path=recon_path, frames_path=frames_path, floor=floor).query(text, pose)


def parse_pose(text: str, *, degrees: bool = False) -> tuple[float, float, float]:
    """``"x,y,yaw"`` (metres, metres, radians; degrees when ``degrees``, as the CLI's ``--pose`` takes it) ->
    ``(x, y, yaw radians)``; raises InputDataError naming ``--pose`` and the expected form."""
    import math

    from pipeline.errors import InputDataError

    parts = [p for p in text.replace(" ", "").split(",") if p]
    unit = "degrees" if degrees else "radians"
    try:
        if len(parts) != 3:
            raise ValueError
        x, y, yaw = (float(p) for p in parts)
    except ValueError:
        raise InputDataError(f"got {text!r}", field="--pose", expected=f"x,y,yaw in metres, metres, {unit}") from None
    if not all(map(math.isfinite, (x, y, yaw))):
        raise InputDataError(f"got {text!r}", field="--pose", expected=f"finite x,y,yaw in metres, metres, {unit}")
    return x, y, math.radians(yaw) if degrees else yaw
