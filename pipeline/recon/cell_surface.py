"""Per-cell figures of a floor's grids read from the surface points (:mod:`pipeline.recon.grids` defines them):
the points of the obstacle band in each cell, the highest point of each cell and its colour, and the face test
that clears a cell whose centre lies in front of the faces passing by it. Each takes the points a chunk (or a
tile) at a time and gives what it gives on all of them at once.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pipeline.config import ReconstructParams
from pipeline.geometry import GridSpec
from pipeline.recon.surface import COLUMNS, Surface

# in_front_of_faces: every side-facing point (|n_z| < 0.3) within 0.4 cell of a centre votes (at least 5:
# a face's points over the band's height); an upward/downward-facing point within 5 mm of the centre means
# a top or underside over it.
_FACE_NZ, _FACE_RADIUS_CELLS, _FACE_MIN_POINTS, _FLAT_NZ, _FLAT_RADIUS_M = 0.3, 0.4, 5, 0.7, 0.005
_FACE_BLOCK_ENTRIES = 1 << 19  # candidate cells x neighbours per block (~50 MB of neighbour arrays)


def surface_occupancy(grid: GridSpec, floor_z: float, xyz: np.ndarray, normals: np.ndarray, p: ReconstructParams
                      ) -> np.ndarray:
    """``(rows, cols)`` bool: cells holding ``surface_min_points`` surface points of the band, moved half a cell in.

    Normals point out of solids (toward the cameras), so a point moved by half a cell against its
    normal lies in a cell whose centre is inside the solid: the same rasterisation as the column
    test, for surfaces whose voxels were thinned out by fusion (chair legs, thin panels). A face
    passing a few millimetres outside a cell centre sends a stray point or two into that cell;
    ``surface_min_points`` keeps those out.
    """
    return (surface_counts(grid, floor_z, xyz, normals, p) >= p.surface_min_points).reshape(grid.rows, grid.cols)


def surface_counts(grid: GridSpec, floor_z: float, xyz: np.ndarray, normals: np.ndarray, p: ReconstructParams
                   ) -> np.ndarray:
    """``(rows * cols,)`` int64: the band's points in each cell, moved half a cell in (:func:`surface_occupancy`;
    counts of chunks add up)."""
    z_rel = xyz[:, 2] - floor_z
    band = (z_rel >= p.obstacle_min_height_m) & (z_rel <= p.obstacle_max_height_m)
    moved = xyz[band, :2] - 0.5 * grid.cell_size_m * normals[band, :2]
    rc = grid.world_to_cell(moved)
    rc = rc[grid.inside(rc)]
    return np.bincount(rc[:, 0] * grid.cols + rc[:, 1], minlength=grid.rows * grid.cols)


def in_front_of_faces(grid: GridSpec, floor_z: float, xyz: np.ndarray, normals: np.ndarray, candidates: np.ndarray,
                      solid_z: np.ndarray, p: ReconstructParams) -> np.ndarray:
    """``(rows, cols)`` bool: ``candidates`` whose centre lies in front of the vertical faces passing by it.

    The column and surface tests read voxel signs, which fusion blurs by a few millimetres near
    faces (grazing views, views past convex corners); a face passing just outside a cell centre then
    occupies the cell. The extracted surface is sharper (interpolated zero crossings): for each
    candidate, the side-facing surface points of the band within 0.4 cell of its centre (xy) vote
    with their signed distance to the centre along their normals; a positive median (the centre is
    in front) clears it — provided the voting faces span the heights where the column saw solid
    (``solid_z`` from :class:`Columns`: a seat under a backrest keeps its cell). Cells with an
    upward- or downward-facing point over the centre (a top) keep their evidence, as do cells with
    fewer than five nearby points (inside thick solids). Candidates go in blocks (bounded memory).

    Every point within the radius votes, not the nearest few: a face's points stack in columns at
    one xy, so a cap on the neighbour count would cut through points tied in distance, and which of
    them are kept would depend on the order of ``xyz`` (open3d's hash-map order, which changes from
    run to run). The result is a function of the point set alone.
    """
    out = np.zeros((grid.rows, grid.cols), dtype=bool)
    z_rel = xyz[:, 2] - floor_z
    band = (z_rel >= p.obstacle_min_height_m) & (z_rel <= p.obstacle_max_height_m)
    side = band & (np.abs(normals[:, 2]) < _FACE_NZ)
    flat = band & (np.abs(normals[:, 2]) >= _FLAT_NZ)
    if not candidates.any() or side.sum() < _FACE_MIN_POINTS:
        return out
    pts = xyz[side, :2].astype(np.float64)
    pts_z = z_rel[side]
    nxy = normals[side, :2].astype(np.float64)
    nxy /= np.linalg.norm(nxy, axis=1, keepdims=True)
    side_tree = cKDTree(pts)
    flat_tree = cKDTree(xyz[flat, :2].astype(np.float64)) if flat.any() else None
    radius = _FACE_RADIUS_CELLS * grid.cell_size_m
    all_rc = np.argwhere(candidates)
    all_centres = grid.cell_to_world(all_rc)
    most = int(side_tree.query_ball_point(all_centres, radius, return_length=True).max())
    if most < _FACE_MIN_POINTS:
        return out
    k = most + 1  # one column more than any disc holds, so none is cut (checked below)
    block = max(1, _FACE_BLOCK_ENTRIES // k)
    for start in range(0, len(all_rc), block):
        rc, centres = all_rc[start : start + block], all_centres[start : start + block]
        dist, idx = side_tree.query(centres, k=k, distance_upper_bound=radius)
        while np.isfinite(dist[:, -1]).any():  # the disc count and the k-nearest bound disagreed by a rounding
            k *= 2
            dist, idx = side_tree.query(centres, k=k, distance_upper_bound=radius)
        near = np.isfinite(dist)
        j = np.where(near, idx, 0)
        signed = np.where(near, np.einsum("nkd,nkd->nk", centres[:, None, :] - pts[j], nxy[j]), np.nan)
        face_z = np.where(near, pts_z[j], np.nan)
        enough = near.sum(axis=1) >= _FACE_MIN_POINTS
        if not enough.any():
            continue
        median = np.full(len(rc), np.nan)
        median[enough] = np.nanmedian(signed[enough], axis=1)
        front = enough & (median > 0)
        # Solid seen in the column must lie within the heights of the voting faces (one voxel of slack).
        solid = solid_z[rc[:, 0], rc[:, 1]]
        z_lo = np.full(len(rc), np.inf)
        z_hi = np.full(len(rc), -np.inf)
        z_lo[enough] = np.nanmin(face_z[enough], axis=1)
        z_hi[enough] = np.nanmax(face_z[enough], axis=1)
        spanned = (solid[:, 0] >= z_lo - p.voxel_size_m) & (solid[:, 1] <= z_hi + p.voxel_size_m)
        front &= ~np.isfinite(solid[:, 0]) | spanned
        if flat_tree is not None:
            flat_dist, _ = flat_tree.query(centres, k=1, distance_upper_bound=_FLAT_RADIUS_M)
            front &= ~np.isfinite(flat_dist)
        out[rc[front, 0], rc[front, 1]] = True
    return out


def top_surface(grid: GridSpec, floor_z: float, xyz: np.ndarray, colors: np.ndarray, p: ReconstructParams
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """Height ``(rows, cols)`` float32 (NaN unknown), colour ``(rows, cols, 3)`` uint8, points outside.

    The highest point of each cell (up to ``height_max_m`` above the floor) wins.
    """
    top = TopSurface(grid, floor_z, p)
    top.add(xyz, colors)
    return top.result()


class TopSurface:
    """:func:`top_surface` a chunk of points at a time: the highest point of each cell so far (ties broken by the
    greatest colour, so the winner does not depend on the order the points come in)."""

    def __init__(self, grid: GridSpec, floor_z: float, p: ReconstructParams):
        self.grid, self.floor_z, self.p = grid, floor_z, p
        self.z = np.full(grid.rows * grid.cols, -np.inf)
        self.color = np.zeros((grid.rows * grid.cols, 3), np.uint8)
        self.seen = np.zeros(grid.rows * grid.cols, bool)
        self.outside = 0

    def add(self, xyz: np.ndarray, colors: np.ndarray) -> None:
        grid = self.grid
        rc = grid.world_to_cell(xyz[:, :2])
        inside = grid.inside(rc)
        z = xyz[:, 2].astype(np.float64) - self.floor_z
        keep = inside & (z <= self.p.height_max_m)
        flat = rc[keep, 0] * grid.cols + rc[keep, 1]
        zk, ck = z[keep], colors[keep]
        order = np.lexsort((ck[:, 2], ck[:, 1], ck[:, 0], zk, flat))  # ties broken by colour: deterministic
        flat, zk, ck = flat[order], zk[order], ck[order]
        last = np.r_[flat[1:] != flat[:-1], True] if flat.size else np.zeros(0, bool)
        cell, z_new, c_new = flat[last], zk[last], ck[last].astype(np.int16)
        z_old, c_old = self.z[cell], self.color[cell].astype(np.int16)
        lighter = np.zeros(len(cell), bool)  # the new colour is the greater (r, then g, then b)
        for k in (2, 1, 0):
            lighter = (c_new[:, k] > c_old[:, k]) | ((c_new[:, k] == c_old[:, k]) & lighter)
        better = ~self.seen[cell] | (z_new > z_old) | ((z_new == z_old) & lighter)
        self.z[cell[better]] = z_new[better]
        self.color[cell[better]] = c_new[better]
        self.seen[cell] = True
        self.outside += int((~inside).sum())

    def result(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Height ``(rows, cols)`` float32 (NaN unknown), colour ``(rows, cols, 3)`` uint8, points outside."""
        height = np.where(self.seen, self.z, np.nan).astype(np.float32)
        shape = (self.grid.rows, self.grid.cols)
        return height.reshape(shape), self.color.reshape(shape + (3,)), self.outside


def band_chunks(surface: Surface, band: tuple[float, float] | None, columns=COLUMNS):
    """The surface's points with world height in ``band`` ``[lo, hi)`` (None: all), a chunk at a time."""
    for chunk in surface.chunks(columns):
        if band is None:
            yield chunk
            continue
        z = chunk[0][:, 2]
        keep = (z >= band[0]) & (z < band[1])
        yield tuple(c[keep] for c in chunk)


def faces_cleared(grid: GridSpec, floor_z: float, surface: Surface, band: tuple[float, float] | None,
                  candidates: np.ndarray, solid_z: np.ndarray, p: ReconstructParams) -> np.ndarray:
    """:func:`in_front_of_faces` tile by tile: each candidate votes with the points of ``band`` within reach, read
    from the tile owning its centre and the tiles beside it (a few centimetres, well inside a neighbour), so the
    result is that of all the points at once."""
    out = np.zeros((grid.rows, grid.cols), dtype=bool)
    cells = np.argwhere(candidates)
    if not len(cells):
        return out
    centres = grid.cell_to_world(cells)
    owner = surface.tile_of(centres)
    reach = max(_FACE_RADIUS_CELLS * grid.cell_size_m, _FLAT_RADIUS_M) + p.voxel_size_m
    for tile in np.unique(owner, axis=0):
        here = (owner == tile).all(axis=1)
        c = centres[here]
        box = (c[:, 0].min() - reach, c[:, 0].max() + reach, c[:, 1].min() - reach, c[:, 1].max() + reach)
        xyz, normals = surface.near((int(tile[0]), int(tile[1])), box, ("xyz", "normals"))
        if band is not None:
            keep = (xyz[:, 2] >= band[0]) & (xyz[:, 2] < band[1])
            xyz, normals = xyz[keep], normals[keep]
        mine = np.zeros_like(candidates)
        mine[cells[here, 0], cells[here, 1]] = True
        out |= in_front_of_faces(grid, floor_z, xyz, normals, mine, solid_z, p)
    return out
