"""Filling the unseen tops of tall objects: after fusion, before the map is written (:func:`fill_unseen`)."""

from __future__ import annotations

import numpy as np
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fusion import FusedCells


def fill_unseen(cells: FusedCells, grid: GridSpec, fillable: np.ndarray, radius_m: float) -> tuple[FusedCells, int]:
    """Give unobserved ``fillable`` cells in HOLES of the map (enclosed by observed cells) within
    ``radius_m`` the feature of the nearest observed cell.

    A robot camera below an object's top never sees the inside of its footprint (a 1.2 m cabinet
    seen from 0.88 m shows only its faces, which enclose it together with the walls); recon marks
    those cells occupied or unknown, never free. The outside of the scene is not a hole. Filled cells get ``count`` 0 and ``weight`` 0 so readers can tell them apart. Returns
    the merged cells (ascending) and how many were filled.
    """
    if radius_m <= 0 or len(cells.cell) == 0:
        return cells, 0
    from scipy.ndimage import binary_fill_holes, distance_transform_edt

    observed = np.zeros(grid.rows * grid.cols, bool)
    observed[cells.cell] = True
    observed = observed.reshape(grid.rows, grid.cols)
    holes = binary_fill_holes(observed) & ~observed  # enclosed by observed cells (not the outside of the scene)
    dist, (nr, nc) = distance_transform_edt(~observed, return_indices=True)
    take = holes & fillable & (dist * grid.cell_size_m <= radius_m)
    tr, tc = np.nonzero(take)
    if not len(tr):
        return cells, 0
    new_cell = tr * grid.cols + tc
    src = np.searchsorted(cells.cell, nr[tr, tc] * grid.cols + nc[tr, tc])
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
