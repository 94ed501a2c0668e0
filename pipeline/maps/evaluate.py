"""Map quality against ground truth (simulated scenes): top-candidate hits and per-class heatmap IoU.

For every ground-truth object class the class name is queried (once without a pose, once from
each given pose). A query HITS when its first candidate's centre lies on a footprint of that
class (``GTScene.instance_footprints``, dilated by ``tolerance_cells`` for rasterisation). The
IoU compares the THRESHOLDED heatmap (probability >= ``threshold``) of the pose-free query with the
union of that class's footprints (unobserved cells count as misses).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_dilation

from pipeline.maps.query import MapQuery


def evaluate_map(mq: MapQuery, gt, poses: list[tuple[float, float, float]] = (), *, tolerance_cells: int = 1,
                 threshold: float = 0.5) -> dict:
    """Figures: ``hit_rate`` over all queries, ``mean_iou``, and per class ``{iou, hits, queries, cells}``."""
    grid = mq.grid
    footprints = gt.instance_footprints(grid)
    per_class = {}
    hits = total = 0
    for cls in sorted({o.cls for o in gt.objects}):
        ids = [o.id for o in gt.objects if o.cls == cls]
        mask = np.isin(footprints, ids)
        near = binary_dilation(mask, iterations=tolerance_cells) if tolerance_cells else mask
        c_hits = c_total = 0
        wins = None
        for pose in [None, *poses]:
            r = mq.query(cls, pose)
            if wins is None:
                wins = np.nan_to_num(r.heatmap, nan=0.0) >= threshold
            top = r.candidates[0] if r.candidates else None
            c_hits += int(top is not None and bool(near[top.center_rc]))
            c_total += 1
        union = (wins | mask).sum()
        per_class[cls] = {"iou": round(float((wins & mask).sum() / union) if union else 0.0, 4), "hits": c_hits,
                          "queries": c_total, "cells": int(mask.sum())}
        hits += c_hits
        total += c_total
    return {"hit_rate": round(hits / max(total, 1), 4), "queries": total,
            "mean_iou": round(float(np.mean([v["iou"] for v in per_class.values()])) if per_class else 0.0, 4),
            "per_class": per_class}


def sample_poses(navigable: np.ndarray, grid, n: int, seed: int = 0) -> list[tuple[float, float, float]]:
    """``n`` deterministic poses on navigable cells with random headings."""
    rr, cc = np.nonzero(navigable)
    if not len(rr):
        return []
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(rr), size=min(n, len(rr)), replace=False)
    xy = grid.cell_to_world(np.stack([rr[pick], cc[pick]], axis=1))
    yaw = rng.uniform(-np.pi, np.pi, len(pick))
    return [(float(x), float(y), float(a)) for (x, y), a in zip(xy, yaw)]
