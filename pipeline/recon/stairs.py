"""Stairs and ramps between floors: connected climbs of walkable surface, found in the reconstruction.

A flight is walkable surface (upward-facing points, binned per grid cell and 5 cm of height) strictly
between two consecutive floors, connected cell to neighbouring cell (8-neighbours, or the same cell) by
steps of at most :data:`MAX_STEP_M` (a riser, or a ramp's rise over a cell), whose low end steps off the
lower floor's surface and whose high end steps onto the upper floor's. Table tops, seats and beds are
walkable-looking surface too, but no chain of small steps leads from the floor onto them, let alone on
to the next floor. Each flight becomes a :class:`~pipeline.recon.store.StairLink`: the landing cells on
either floor's grid (where the flight meets the floor), an endpoint per landing (the navigable cell nearest
the landing's centre, where routes join the floors' grids), its rise, its walked length (the shortest
climb over the flight's surface from its foot to its head, any shape of flight) and that length's
horizontal run, and whether it is stairs (treads at a few heights) or a ramp (every height).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_dilation, distance_transform_edt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from pipeline.config import ReconstructParams
from pipeline.geometry import GridSpec
from pipeline.recon.store import Floor, Landing, StairLink

MAX_STEP_M = 0.25  # the highest riser a flight may have (building codes: about 0.2 m)
_UP_COS = 0.9  # walkable surface faces up within ~25 deg (ramps are far flatter)
_LEVEL_M = 0.05  # height bins of walkable surface within a cell
_MIN_FLIGHT_CELLS = 12  # a flight covers at least this many cells (0.03 m^2 at 5 cm): not a stray speck
_RAMP_FILL = 0.5  # a flight whose heights fill more than this fraction of 2 cm bins over its rise is a ramp
_ENDPOINT_SEARCH_M = 1.0  # a landing's endpoint is the navigable cell nearest its centre within this


def find_stairs(xyz: np.ndarray, normals: np.ndarray, floors: list[Floor], grid: GridSpec,
                navigable: list[np.ndarray], p: ReconstructParams) -> list[StairLink]:
    """The flights joining each pair of consecutive ``floors`` (lowest first), on the floors' shared ``grid``.

    ``xyz``/``normals`` ``(N,3)`` surface points; ``navigable``: each floor's ``(rows, cols)`` bool grid (for
    the landings' endpoints). Returns the links lowest first, numbered from 0.
    """
    up = normals[:, 2] > _UP_COS
    rc = grid.world_to_cell(xyz[up, :2].astype(np.float64))
    inside = grid.inside(rc)
    rc, z = rc[inside], xyz[up, 2][inside].astype(np.float64)
    links: list[StairLink] = []
    for a in range(len(floors) - 1):
        for flight in _flights(rc, z, floors[a].floor_z_m, floors[a + 1].floor_z_m, grid, p.floor_tolerance_m):
            links.append(_link(len(links), flight, floors[a], floors[a + 1], grid, navigable[a], navigable[a + 1]))
    return links


def unlinked_warnings(floors: list[Floor], links: list[StairLink]) -> list[str]:
    """One line per pair of consecutive floors no stairs or ramp joins (routes cannot cross between them)."""
    joined = {(s.bottom.floor, s.top.floor) for s in links}
    return [f"no stairs or ramp joins {lo.name} ({lo.floor_z_m:.2f} m) and {hi.name} ({hi.floor_z_m:.2f} m): no "
            "connected climb of walkable surface between them was reconstructed, so routes cannot cross; record "
            "the stairs (walk them with the camera looking ahead)"
            for lo, hi in zip(floors, floors[1:]) if (lo.id, hi.id) not in joined]


def _flights(rc: np.ndarray, z: np.ndarray, z_lo: float, z_hi: float, grid: GridSpec, tol: float) -> list[dict]:
    """Connected climbs from the floor at ``z_lo`` to the floor at ``z_hi``: dicts of node cells and heights and
    the landing cells on either floor."""
    shape = (grid.rows, grid.cols)
    lower = _mask(rc[np.abs(z - z_lo) <= tol], shape)
    upper = _mask(rc[np.abs(z - z_hi) <= tol], shape)
    mid = (z > z_lo + tol) & (z < z_hi - tol)
    if not mid.any() or not lower.any() or not upper.any():
        return []
    cells, heights = _nodes(rc[mid], z[mid] - z_lo)
    n = len(cells)
    graph = _step_graph(cells, heights, grid.cell_size_m)
    comp = connected_components(graph, directed=False)[1]
    rise = z_hi - z_lo
    low_end = heights <= MAX_STEP_M
    high_end = heights >= rise - MAX_STEP_M
    flat = cells[:, 0] * grid.cols + cells[:, 1]
    near_lower = binary_dilation(lower, np.ones((3, 3), bool)).ravel()[flat]
    near_upper = binary_dilation(upper, np.ones((3, 3), bool)).ravel()[flat]
    starts = np.zeros(comp.max() + 1 if n else 0, bool)
    ends = np.zeros_like(starts)
    np.logical_or.at(starts, comp[low_end & near_lower], True)
    np.logical_or.at(ends, comp[high_end & near_upper], True)
    out = []
    for c in np.flatnonzero(starts & ends):
        member = comp == c
        if len(np.unique(flat[member])) < _MIN_FLIGHT_CELLS:
            continue
        bottom = lower & binary_dilation(_mask(cells[member & low_end], shape), np.ones((3, 3), bool))
        top = upper & binary_dilation(_mask(cells[member & high_end], shape), np.ones((3, 3), bool))
        foot = np.flatnonzero(member & low_end & near_lower)
        head = np.flatnonzero(member & high_end & near_upper)
        length, run = _climb(graph, foot, head, cells, heights, grid.cell_size_m)
        out.append({"cells": cells[member], "heights": heights[member], "bottom": bottom, "top": top,
                    "rise": rise, "length": length, "run": run})
    return out


def _mask(rc: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[rc[:, 0], rc[:, 1]] = True
    return m


def _nodes(rc: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Walkable surface binned per (cell, 5 cm of height): the bins' cells ``(M,2)`` and median heights ``(M,)``,
    sorted by cell then height (a deterministic order)."""
    level = np.floor(h / _LEVEL_M).astype(np.int64)
    keys = np.c_[rc, level]
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.lexsort((h, inverse))
    bounds = np.searchsorted(inverse[order], np.arange(len(uniq) + 1))
    heights = np.array([np.median(h[order[bounds[i]:bounds[i + 1]]]) for i in range(len(uniq))])
    return uniq[:, :2], heights


def _step_graph(cells: np.ndarray, heights: np.ndarray, cell_size_m: float):
    """The nodes' graph (sparse, symmetric): an edge joins neighbouring (or the same) cells whose heights differ by
    at most :data:`MAX_STEP_M`, weighted by the 3-D distance between them (metres; at least 1 mm)."""
    n = len(cells)
    level = np.floor(heights / _LEVEL_M).astype(np.int64)
    reach = int(np.ceil(MAX_STEP_M / _LEVEL_M)) + 1
    span = level.max() - level.min() + 2 * reach + 1
    # one integer key per (row, col, level): neighbours are looked up by key
    base = np.array([(cells[:, 1].max() + 3) * span, span, 1], dtype=np.int64)
    key = (cells[:, 0] + 1) * base[0] + (cells[:, 1] + 1) * base[1] + (level - level.min() + reach)
    order = np.argsort(key)
    sorted_key = key[order]
    src, dst = [], []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            for dl in range(-reach, reach + 1):
                if (dr, dc, dl) <= (0, 0, 0):  # each pair once
                    continue
                want = key + dr * base[0] + dc * base[1] + dl
                j = np.minimum(np.searchsorted(sorted_key, want), n - 1)
                hit = sorted_key[j] == want
                other = order[j[hit]]
                mine = np.flatnonzero(hit)
                close = np.abs(heights[mine] - heights[other]) <= MAX_STEP_M
                src.append(mine[close])
                dst.append(other[close])
    src, dst = np.concatenate(src), np.concatenate(dst)
    flat = np.linalg.norm((cells[src] - cells[dst]).astype(np.float64), axis=1) * cell_size_m
    weight = np.maximum(np.hypot(flat, heights[src] - heights[dst]), 1e-3)
    graph = coo_matrix((np.r_[weight, weight], (np.r_[src, dst], np.r_[dst, src])), shape=(n, n))
    return graph.tocsr()


def _climb(graph, foot: np.ndarray, head: np.ndarray, cells: np.ndarray, heights: np.ndarray, cell_size_m: float
           ) -> tuple[float, float]:
    """The shortest walk over the flight from any ``foot`` node to any ``head`` node: its 3-D length and its
    horizontal run (metres), plus the step onto each floor (one cell, to the floor's height)."""
    dist, pred, _ = dijkstra(graph, indices=foot, min_only=True, return_predecessors=True)
    end = int(head[np.argmin(dist[head])])
    run, node = cell_size_m, end  # one cell from the last tread onto the upper floor
    while pred[node] >= 0:
        run += float(np.linalg.norm((cells[node] - cells[pred[node]]).astype(np.float64))) * cell_size_m
        node = pred[node]
    run += cell_size_m  # and from the lower floor onto the first
    return float(dist[end]) + 2 * cell_size_m, run


def _link(index: int, flight: dict, lower: Floor, upper: Floor, grid: GridSpec, nav_lower: np.ndarray,
          nav_upper: np.ndarray) -> StairLink:
    bottom = _landing(flight["bottom"], lower, nav_lower, grid)
    top = _landing(flight["top"], upper, nav_upper, grid)
    rise, run = float(flight["rise"]), float(flight["run"])
    bins = np.unique(np.floor(flight["heights"] / 0.02))
    kind = "ramp" if len(bins) > _RAMP_FILL * rise / 0.02 else "stairs"
    cells = flight["cells"]
    flat = np.unique(cells[:, 0] * grid.cols + cells[:, 1])
    return StairLink(id=index, kind=kind, bottom=bottom, top=top, rise_m=round(rise, 4), run_m=round(run, 3),
                     length_m=round(max(float(flight["length"]), float(np.hypot(rise, run))), 3),
                     flight_cells=int(len(flat)),
                     flight_bbox=(int(cells[:, 0].min()), int(cells[:, 1].min()), int(cells[:, 0].max()),
                                  int(cells[:, 1].max())))


def _landing(mask: np.ndarray, floor: Floor, navigable: np.ndarray, grid: GridSpec) -> Landing:
    """The landing's cells and its endpoint: the navigable cell nearest the landing's centre within
    :data:`_ENDPOINT_SEARCH_M`, else the landing cell nearest it."""
    cells = np.argwhere(mask)
    centre = cells.mean(axis=0)
    endpoint = cells[np.argmin(np.linalg.norm(cells - centre, axis=1))]
    if navigable.any():
        dist, (ri, ci) = distance_transform_edt(~navigable, return_indices=True)
        r, c = endpoint
        if dist[r, c] * grid.cell_size_m <= _ENDPOINT_SEARCH_M:
            endpoint = np.array([ri[r, c], ci[r, c]])
    return Landing(floor=floor.id, cells=[(int(r), int(c)) for r, c in cells],
                   endpoint=(int(endpoint[0]), int(endpoint[1])), z_m=round(float(floor.floor_z_m), 4))
