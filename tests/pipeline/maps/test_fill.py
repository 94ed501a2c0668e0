"""Filling enclosed holes of a fused map, hand-computed."""

import numpy as np
import torch

from pipeline.geometry import GridSpec
from pipeline.maps.fill import fill_unseen
from pipeline.maps.fusion import FusedCells


def test_fill_unseen_fills_enclosed_holes_within_the_radius():
    grid = GridSpec(rows=5, cols=5, cell_size_m=1.0, origin_xy=(0.0, 5.0))
    ring = [r * 5 + c for r in range(4) for c in range(4) if r in (0, 3) or c in (0, 3)]  # a 4x4 ring, ascending
    a, b = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    feats = torch.tensor([b if cell == 5 else a for cell in ring])  # (1, 0), next to the hole cell (1, 1), is b
    n = len(ring)
    cells = FusedCells(np.array(ring), feats, np.ones(n, np.float32), np.ones(n, np.int32), np.ones(n, np.int16))
    fillable = np.ones((5, 5), bool)
    fillable[2, 2] = False  # recon says free: never filled
    out, filled = fill_unseen(cells, grid, fillable, radius_m=1.0)
    # holes: (1,1), (1,2), (2,1), (2,2); (2,2) is not fillable; cells outside the ring are not holes
    assert filled == 3 and sorted(set(out.cell) - set(ring)) == [6, 7, 11]
    assert out.cell.tolist() == sorted(out.cell.tolist())
    i = out.cell.tolist().index(6)
    assert out.count[i] == 0 and out.weight[i] == 0 and out.level[i] == 1
    assert out.features[i].tolist() in (a, b)  # the nearest observed cell's: (0, 1) holds a, (1, 0) holds b
    assert out.features[out.cell.tolist().index(7)].tolist() == a  # (1, 2): nearest is (0, 2)
    same, none = fill_unseen(cells, grid, fillable, radius_m=0.0)
    assert none == 0 and same is cells
