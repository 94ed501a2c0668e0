"""Stairs and ramps between floors: connected climbs of walkable surface, found in the reconstruction.

A flight is walkable surface (upward-facing points, binned per grid cell and 5 cm of height) strictly
between two consecutive floors, connected from cell to cell at most :data:`MAX_GAP_M` away (a tread seen only
in patches, at grazing angles, still joins the next) by steps of at most :data:`MAX_STEP_M` (a riser, or a
ramp's rise), whose low end steps off the lower floor's surface and whose high end steps onto the upper
floor's (within :data:`MAX_GAP_M` of them). Table tops, seats and beds are
walkable-looking surface too, but no chain of small steps leads from the floor onto them, let alone on
to the next floor. Each flight becomes a :class:`~pipeline.recon.store.StairLink`: the landing cells on
either floor's grid (where the flight meets the floor), an endpoint per landing (the navigable cell nearest
the landing's centre, where routes join the floors' grids), its rise, its walked length (the shortest
climb over the flight's surface from its foot to its head, any shape of flight) and that length's
horizontal run, and whether it is stairs (treads at a few heights) or a ramp (every height).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_closing, binary_fill_holes, distance_transform_edt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from pipeline.config import ReconstructParams
from pipeline.geometry import GridSpec
from pipeline.recon.store import Floor, Landing, StairLink
from pipeline.recon.surface import Surface

MAX_STEP_M = 0.25  # the highest riser a flight may have (building codes: about 0.2 m)
MAX_GAP_M = 0.3  # walkable surface this close (along x and y) joins: a tread seen only in patches, 0.28 m deep
_UP_COS = 0.9  # walkable surface faces up within ~25 deg (ramps are far flatter)
_LEVEL_M = 0.05  # height bins of walkable surface within a cell
_MIN_FLIGHT_CELLS = 12  # a flight covers at least this many cells (0.03 m^2 at 5 cm): not a stray speck
_RAMP_FILL = 0.5  # a flight whose heights fill more than this fraction of 2 cm bins over its rise is a ramp
_ENDPOINT_SEARCH_M = 1.0  # a landing's endpoint is the navigable cell nearest its centre within this


@dataclass
class Flight:
    """One climb found between floors ``lower`` and ``upper`` (indices into the floor list): its nodes' cells
    ``(M,2)`` and heights above the lower floor ``(M,)``, the landing masks on either floor's grid, the rise and
    the shortest walk over it (``length`` 3-D, ``run`` horizontal), metres."""

    lower: int
    upper: int
    cells: np.ndarray
    heights: np.ndarray
    bottom: np.ndarray
    top: np.ndarray
    rise: float
    length: float
    run: float

    def mask(self, shape: tuple[int, int]) -> np.ndarray:
        """``(rows, cols)`` bool: the cells the flight's walkable surface was seen in."""
        return _mask(self.cells, shape)

    def footprint(self, shape: tuple[int, int], cell_size_m: float) -> np.ndarray:
        """``(rows, cols)`` bool: the ground the flight stands on, :meth:`mask` with the gaps between the patches it
        joins filled (treads seen only in parts join across up to :data:`MAX_GAP_M` along x and y, so the flight
        covers the cells between them: a closing by a square of side ``MAX_GAP_M``, holes filled). The flight's
        solid on the floor it rises from, the stairwell's void on the floor it arrives on."""
        r = int(np.ceil(MAX_GAP_M / 2 / cell_size_m))
        seen = np.pad(self.mask(shape), r)  # room for the closing at the grid's edge
        return binary_fill_holes(binary_closing(seen, structure=np.ones((2 * r + 1, 2 * r + 1), bool)))[r:-r, r:-r]


def find_flights(surface: Surface, floors: list[Floor], grid: GridSpec, p: ReconstructParams) -> list[Flight]:
    """The flights joining each pair of consecutive ``floors`` (lowest first), on the floors' shared ``grid``.

    ``surface`` is read a chunk at a time: what is kept of it are the floors' cells (masks) and the candidates of
    a climb, the upward-facing points strictly between two floors."""
    shape, tol = (grid.rows, grid.cols), p.floor_tolerance_m
    heights = [f.floor_z_m for f in floors]
    on_floor = [np.zeros(shape, bool) for _ in floors]
    between: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in floors[1:]]
    for xyz, normals in surface.chunks(("xyz", "normals")):
        up = normals[:, 2] > _UP_COS
        rc = grid.world_to_cell(xyz[up, :2].astype(np.float64))
        inside = grid.inside(rc)
        rc, z = rc[inside], xyz[up, 2][inside].astype(np.float64)
        for k, z_k in enumerate(heights):
            on_floor[k] |= _mask(rc[np.abs(z - z_k) <= tol], shape)
        for a, (z_lo, z_hi) in enumerate(zip(heights, heights[1:])):
            mid = (z > z_lo + tol) & (z < z_hi - tol)
            between[a].append((rc[mid], z[mid]))
    out = []
    for a, (z_lo, z_hi) in enumerate(zip(heights, heights[1:])):
        rc = np.concatenate([r for r, _ in between[a]]) if between[a] else np.zeros((0, 2), np.int64)
        z = np.concatenate([h for _, h in between[a]]) if between[a] else np.zeros(0)
        out += [Flight(a, a + 1, **f) for f in _flights(on_floor[a], on_floor[a + 1], rc, z, z_lo, z_hi, grid)]
    return out


def stair_links(flights: list[Flight], floors: list[Floor], grid: GridSpec, navigable: list[np.ndarray]
                ) -> list[StairLink]:
    """Each flight as a :class:`StairLink` numbered from 0; ``navigable``: each floor's ``(rows, cols)`` bool grid
    (the landings' endpoints are navigable cells)."""
    return [_link(i, f, floors[f.lower], floors[f.upper], grid, navigable[f.lower], navigable[f.upper])
            for i, f in enumerate(flights)]


def find_stairs(surface: Surface, floors: list[Floor], grid: GridSpec, navigable: list[np.ndarray],
                p: ReconstructParams) -> list[StairLink]:
    """:func:`find_flights` as :func:`stair_links`."""
    return stair_links(find_flights(surface, floors, grid, p), floors, grid, navigable)


def unlinked_warnings(floors: list[Floor], links: list[StairLink]) -> list[str]:
    """One line per pair of consecutive floors no stairs or ramp joins (routes cannot cross between them)."""
    joined = {(s.bottom.floor, s.top.floor) for s in links}
    return [f"no stairs or ramp joins {lo.name} ({lo.floor_z_m:.2f} m) and {hi.name} ({hi.floor_z_m:.2f} m): no "
            "connected climb of walkable surface between them was reconstructed, so routes cannot cross; record "
            "the stairs (walk them with the camera looking ahead)"
            for lo, hi in zip(floors, floors[1:]) if (lo.id, hi.id) not in joined]


def _flights(lower: np.ndarray, upper: np.ndarray, rc: np.ndarray, z: np.ndarray, z_lo: float, z_hi: float,
             grid: GridSpec) -> list[dict]:
    """Connected climbs from the floor at ``z_lo`` to the floor at ``z_hi``: dicts of node cells and heights and
    the landing cells on either floor. ``lower``/``upper``: ``(rows, cols)`` bool, the cells of walkable surface on
    either floor; ``rc`` ``(M,2)``/``z`` ``(M,)``: the walkable points strictly between them."""
    shape = (grid.rows, grid.cols)
    if not len(z) or not lower.any() or not upper.any():
        return []
    cells, heights = _nodes(rc, z - z_lo)
    n = len(cells)
    graph = _step_graph(cells, heights, grid.cell_size_m)
    comp = connected_components(graph, directed=False)[1]
    rise = z_hi - z_lo
    low_end = heights <= MAX_STEP_M
    high_end = heights >= rise - MAX_STEP_M
    flat = cells[:, 0] * grid.cols + cells[:, 1]
    reach = MAX_GAP_M / grid.cell_size_m
    to_lower = distance_transform_edt(~lower).ravel()[flat] * grid.cell_size_m  # metres to the floor, in x, y
    to_upper = distance_transform_edt(~upper).ravel()[flat] * grid.cell_size_m
    near_lower, near_upper = to_lower <= MAX_GAP_M, to_upper <= MAX_GAP_M
    starts = np.zeros(comp.max() + 1 if n else 0, bool)
    ends = np.zeros_like(starts)
    np.logical_or.at(starts, comp[low_end & near_lower], True)
    np.logical_or.at(ends, comp[high_end & near_upper], True)
    out = []
    for c in np.flatnonzero(starts & ends):
        member = comp == c
        if len(np.unique(flat[member])) < _MIN_FLIGHT_CELLS:
            continue
        bottom = lower & (distance_transform_edt(~_mask(cells[member & low_end & near_lower], shape)) <= reach)
        top = upper & (distance_transform_edt(~_mask(cells[member & high_end & near_upper], shape)) <= reach)
        foot = np.flatnonzero(member & low_end & near_lower)
        head = np.flatnonzero(member & high_end & near_upper)
        length, run = _climb(graph, (foot, to_lower[foot], heights[foot]), (head, to_upper[head], rise - heights[head]),
                             cells, grid.cell_size_m)
        out.append({"cells": cells[member], "heights": heights[member], "bottom": bottom, "top": top,
                    "rise": float(rise), "length": length, "run": run})
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
    """The nodes' graph (sparse, symmetric): an edge joins nodes at most :data:`MAX_GAP_M` apart along x and along y
    whose heights differ by at most :data:`MAX_STEP_M` (a tread seen only in patches still joins the next), weighted
    by the 3-D distance between them (metres; at least 1 mm)."""
    n = len(cells)
    scale = MAX_GAP_M / MAX_STEP_M  # heights scaled so one Chebyshev radius bounds both
    pts = np.c_[cells.astype(np.float64) * cell_size_m, heights * scale]
    pairs = cKDTree(pts).query_pairs(MAX_GAP_M + 1e-9, p=np.inf, output_type="ndarray")
    src, dst = pairs[:, 0], pairs[:, 1]
    flat = np.linalg.norm((cells[src] - cells[dst]).astype(np.float64), axis=1) * cell_size_m
    weight = np.maximum(np.hypot(flat, heights[src] - heights[dst]), 1e-3)
    graph = coo_matrix((np.r_[weight, weight], (np.r_[src, dst], np.r_[dst, src])), shape=(n, n))
    return graph.tocsr()


def _climb(graph, foot: tuple, head: tuple, cells: np.ndarray, cell_size_m: float) -> tuple[float, float]:
    """The shortest walk from the lower floor over the flight onto the upper floor: its 3-D length and its
    horizontal run (metres). ``foot``/``head``: (nodes, metres to the floor along x-y, height to it) of the nodes
    that step off the lower floor / onto the upper one; a start and an end node joined to them carry those steps."""
    n = graph.shape[0]
    start, end = n, n + 1
    ends = [(start, *foot), (end, *head)]
    src = np.concatenate([np.full(len(nodes), v) for v, nodes, _, _ in ends])
    dst = np.concatenate([nodes for _, nodes, _, _ in ends])
    flat_m = np.concatenate([d for _, _, d, _ in ends])
    weight = np.maximum(np.hypot(flat_m, np.concatenate([h for _, _, _, h in ends])), 1e-3)
    g = graph.tocoo()
    full = coo_matrix((np.r_[g.data, weight, weight], (np.r_[g.row, src, dst], np.r_[g.col, dst, src])),
                      shape=(n + 2, n + 2)).tocsr()
    dist, pred = dijkstra(full, indices=start, return_predecessors=True)
    step_flat = dict(zip(zip(src.tolist(), dst.tolist()), flat_m.tolist()))
    run, node = 0.0, end
    while pred[node] >= 0:
        prev = int(pred[node])
        if node >= n or prev >= n:
            run += step_flat[(max(node, prev), min(node, prev))]
        else:
            run += float(np.linalg.norm((cells[node] - cells[prev]).astype(np.float64))) * cell_size_m
        node = prev
    return float(dist[end]), run


def _link(index: int, flight: Flight, lower: Floor, upper: Floor, grid: GridSpec, nav_lower: np.ndarray,
          nav_upper: np.ndarray) -> StairLink:
    bottom = _landing(flight.bottom, lower, nav_lower, grid)
    top = _landing(flight.top, upper, nav_upper, grid)
    rise, run = flight.rise, flight.run
    bins = np.unique(np.floor(flight.heights / 0.02))
    kind = "ramp" if len(bins) > _RAMP_FILL * rise / 0.02 else "stairs"
    cells = flight.cells
    flat = np.unique(cells[:, 0] * grid.cols + cells[:, 1])
    return StairLink(id=index, kind=kind, bottom=bottom, top=top, rise_m=round(rise, 4), run_m=round(run, 3),
                     length_m=round(max(flight.length, float(np.hypot(rise, run))), 3),
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
    x, y = grid.cell_to_world(endpoint[None, :].astype(np.int64))[0]
    return Landing(floor=floor.id, cells=[(int(r), int(c)) for r, c in cells],
                   endpoint=(int(endpoint[0]), int(endpoint[1])), xy=(round(float(x), 4), round(float(y), 4)),
                   z_m=round(float(floor.floor_z_m), 4))
