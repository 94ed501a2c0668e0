"""Filling the unseen tops of tall objects: after fusion, before the map is written (:func:`fill_unseen`)."""

from __future__ import annotations

import numpy as np
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fusion import FusedCells


def fill_targets(cell: np.ndarray, grid: GridSpec, fillable: np.ndarray, radius_m: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(new_cell, source_cell)`` ``(K,)`` int64 flat cells, ``new_cell`` ascending: the unobserved ``fillable``
    cells in HOLES of the map (enclosed by the observed cells ``cell``) within ``radius_m`` of an observed cell,
    and the nearest observed cell of each, whose feature and level it takes (:func:`fill_unseen`).

    Needs only the observed cells (any order) and ``(rows, cols)`` masks: a map folded one tile at a time
    (:mod:`pipeline.maps.tilefold`) plans its filling before any feature is read."""
    none = np.zeros(0, np.int64)
    if radius_m <= 0 or len(cell) == 0:
        return none, none
    from scipy.ndimage import binary_fill_holes, distance_transform_edt

    observed = np.zeros(grid.rows * grid.cols, bool)
    observed[cell] = True
    observed = observed.reshape(grid.rows, grid.cols)
    holes = binary_fill_holes(observed) & ~observed  # enclosed by observed cells (not the outside of the scene)
    dist, (nr, nc) = distance_transform_edt(~observed, return_indices=True)
    take = holes & fillable & (dist * grid.cell_size_m <= radius_m)
    tr, tc = np.nonzero(take)
    return (tr * grid.cols + tc).astype(np.int64), (nr[tr, tc] * grid.cols + nc[tr, tc]).astype(np.int64)


def fill_unseen(cells: FusedCells, grid: GridSpec, fillable: np.ndarray, radius_m: float) -> tuple[FusedCells, int]:
    """Give unobserved ``fillable`` cells in HOLES of the map (enclosed by observed cells) within
    ``radius_m`` the feature of the nearest observed cell (:func:`fill_targets`).

    A robot camera below an object's top never sees the inside of its footprint (a 1.2 m cabinet
    seen from 0.88 m shows only its faces, which enclose it together with the walls); recon marks
    those cells occupied or unknown, never free. The outside of the scene is not a hole. Filled cells get
    ``count`` 0 and ``weight`` 0 so readers can tell them apart. Returns the merged cells (ascending) and how
    many were filled.
    """
    new_cell, source = fill_targets(cells.cell, grid, fillable, radius_m)
    if not len(new_cell):
        return cells, 0
    src = np.searchsorted(cells.cell, source)
    all_cell = np.concatenate([cells.cell, new_cell])
    order = np.argsort(all_cell, kind="stable")
    feats = torch.cat([cells.features, cells.features[torch.from_numpy(src)]])[torch.from_numpy(order)]
    zeros = np.zeros(len(new_cell))
    return FusedCells(
        cell=all_cell[order],
        features=feats,
        weight=np.concatenate([cells.weight, zeros.astype(np.float32)])[order],
        count=np.concatenate([cells.count, zeros.astype(np.int32)])[order],
        level=np.concatenate([cells.level, cells.level[src]])[order],
    ), int(len(new_cell))
