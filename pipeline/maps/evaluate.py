"""Map quality against ground truth (simulated scenes): top-candidate hits and per-class heatmap IoU.

For every ground-truth object class the class name is queried (once without a pose, once from
each given pose). A query HITS when its first candidate's centre lies on a footprint of that
class (``GTScene.instance_footprints``, dilated by ``tolerance_cells`` for rasterisation). The
IoU compares the THRESHOLDED heatmap (probability >= ``threshold``) of the pose-free query with the
union of that class's footprints (unobserved cells count as misses).

Thin objects: ``instance_footprints`` paints the cells whose CENTRES lie inside a part, so a
picture 3 cm thick on a wall (5 cm cells) may own no cell at all and could never be hit. An object
with no footprint cell takes the cells its parts overlap instead (:func:`class_masks`).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_dilation

from pipeline.maps.query import MapQuery


def evaluate_map(mq: MapQuery, gt, poses: list[tuple[float, float, float]] = (), *, tolerance_cells: int = 1,
                 threshold: float = 0.5) -> dict:
    """Figures: ``hit_rate`` over all queries, ``mean_iou``, and per class ``{iou, hits, queries, cells}``."""
    grid = mq.grid
    masks = class_masks(gt, grid)
    per_class = {}
    hits = total = 0
    for cls in sorted(masks):
        mask = masks[cls]
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


def class_masks(gt, grid) -> dict[str, np.ndarray]:
    """Per class ``(rows, cols)`` bool: its objects' footprints (``GTScene.instance_footprints``, taller parts
    win); an object with no footprint cell (thinner than a cell, or wholly under a taller object) takes
    every cell its parts overlap."""
    footprints = gt.instance_footprints(grid)
    out: dict[str, np.ndarray] = {}
    for o in gt.objects:
        own = footprints == o.id
        if not own.any():
            for p in o.parts:
                (r0, c0), (r1, c1) = grid.world_to_cell(np.array([[p.min[0], p.max[1]], [p.max[0], p.min[1]]]))
                r0, c0 = max(int(r0), 0), max(int(c0), 0)
                r1, c1 = min(int(r1), grid.rows - 1), min(int(c1), grid.cols - 1)
                if r0 <= r1 and c0 <= c1:
                    own[r0 : r1 + 1, c0 : c1 + 1] = True
        out[o.cls] = out[o.cls] | own if o.cls in out else own
    return out


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
