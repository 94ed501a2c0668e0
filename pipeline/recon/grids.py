"""Top-down grids from a fused TSDF volume: floor height, occupancy, navigable mask, colour, height.

All grids live on one :class:`pipeline.geometry.GridSpec` (north-up; it alone maps world x, y to
row, col). Definitions (heights are above the estimated floor ``floor_z``):

- **occupied** (code 2): some voxel of the cell-centre column with height in
  ``[obstacle_min_height_m, obstacle_max_height_m]``, observed at least ``occupancy_min_weight``
  times, lies behind a surface (negative TSDF); or the column shows the top of a solid whose inside
  was never observed (:func:`solid_tops`: a voxel just in front of a surface below it with nothing
  observed under it, or a flat patch of columns with a run of at most 7.5 cm never observed between
  seen air — a thin table top or seat seen only at grazing angles from above, whose inside fusion never
  reaches); or ``surface_min_points`` surface points of that band, moved half
  a cell into the solid along their normals, lie in the cell (:func:`pipeline.recon.cell_surface.surface_occupancy`).
  Voxels seen once count. The grid origin is snapped so that every cell centre is a
  voxel-lattice column, which makes the test "is the cell centre inside geometry" — the
  rasterisation the ground truth uses (:meth:`GTScene.occupancy`). Vertical structures thinner
  than a voxel between cell centres can be missed.
  A 3x3 closing fills unobserved one-cell gaps between occupied cells (never observed floor).
  Unknown regions walled in by occupied cells alone (the unseen inside of a cabinet) become
  occupied when smaller than ``fill_enclosed_max_m2``; unknown cells closer to occupied than to
  free cells (and within ``hidden_solid_max_m``: the unseen back of furniture) become occupied when
  no air low above the floor was seen at the cell centre (a positive-TSDF voxel below
  ``hidden_free_max_height_m``: a gap between furniture and a wall seen from above) and they lie
  inside the building (:func:`building_mask`: the observed area closed by
  ``building_closing_m``) in an unknown region no bigger than ``fill_enclosed_max_m2``, never in
  the unknown world outside it or in a room never entered.
  Last, an occupied cell whose centre lies in front of the vertical faces passing within 0.4 cell
  of it (the median signed distance of their extracted surface points, :func:`~pipeline.recon.cell_surface.in_front_of_faces`)
  is cleared: voxel signs near faces are blurred by a few millimetres (grazing views, views past
  convex corners), the interpolated surface much less.
- **free** (code 1): not occupied, and the floor was observed at the cell centre (a voxel observed
  ``occupancy_min_weight`` times, behind or within half a voxel of a surface, within
  ``floor_tolerance_m`` of the floor).
- **unknown** (code 0): everything else (navchat's codes: 0 unknown, 1 free, 2 occupied).
- **navigable**: free and farther than ``robot_radius_m`` from every occupied cell centre
  (:func:`navigable_mask`; ground truth is dilated with the same function).
- **height** / **color**: the highest surface point in the cell (at most ``height_max_m`` above
  the floor, which leaves ceilings out), NaN / black where nothing was seen.

Each floor's grids are built on its own floor height (:mod:`pipeline.recon.floors` finds the floors)
from the surface of its band (:func:`pipeline.recon.store.floor_bands`); every floor of a scene shares one
grid placement (:func:`place_grid`), so a cell is the same place on every floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np
from scipy.ndimage import binary_closing, binary_dilation, binary_fill_holes, distance_transform_edt, label

from pipeline.config import GridParams, ReconstructParams
from pipeline.errors import ConfigError, InputDataError, StageError
from pipeline.geometry import GridSpec
from pipeline.recon import surface as surface_mod
from pipeline.recon.cell_surface import TopSurface, band_chunks, faces_cleared, surface_counts
from pipeline.recon.store import FREE, OCCUPIED, TILE, UNKNOWN, Grids
from pipeline.recon.surface import Surface

_GROW_MARGIN_M = 1.0  # grid.extent 'grow': the surface's percentile box plus this on each side must fit
_GROW_MAX_CELLS = 20_000  # ... and a grid side longer than this (1 km at 5 cm) is a wrong pose, not a building
# solid_tops: a voxel closer than 0.9 truncation distances in front of a surface, with the voxel
# above it at least 0.1 farther (a horizontal surface below; a vertical face keeps tsdf constant).
_SOLID_TOP_MAX_TSDF = 0.9
_SOLID_TOP_MIN_RISE = 0.1
_SLAB_MAX_M = 0.075  # solid_tops: an unobserved run at most this tall between seen free space is a thin board
_SLAB_MIN_AREA_M2 = 0.25  # ... where such cells form a patch at least this big


# ----------------------------------------------------------------------------- grid placement

def lattice_ratio(grid: GridParams, p: ReconstructParams) -> int:
    """Voxels per cell edge; the cell size must be a whole multiple of the voxel size."""
    n = grid.cell_size_m / p.voxel_size_m
    if abs(n - round(n)) > 1e-6 or round(n) < 1:
        raise ConfigError(
            f"grid.cell_size_m ({grid.cell_size_m}) must be a whole multiple of reconstruct.voxel_size_m "
            f"({p.voxel_size_m}) so cell centres fall on the TSDF lattice"
        )
    return int(round(n))


def place_grid(xyz: np.ndarray, grid: GridParams, p: ReconstructParams) -> GridSpec:
    """A grid of ``grid.rows x grid.cols`` centred on ``grid.centre_xy`` when pinned, else on the surface
    (0.5-99.5 percentile box of ``xyz`` ``(N,3)``, metres; more frames may move it).

    With ``grid.extent`` 'grow' and no pinned centre, a surface whose box (plus :data:`_GROW_MARGIN_M` each side)
    does not fit makes the grid the smallest whole number of :data:`TILE`-cell tiles covering it on that axis;
    a surface that fits gets exactly the rows x cols grid. The origin is snapped so every cell centre is a TSDF
    lattice column.
    """
    box = None if grid.centre_xy is not None else np.percentile(xyz[:, :2], [0.5, 99.5], axis=0)
    return _placed(box, grid, p)


def surface_box(surface: Surface) -> np.ndarray:
    """``(2, 2)``: the 0.5 and 99.5 percentiles of the surface's x and y (rows), as :func:`place_grid` takes them
    with ``np.percentile`` of the whole array, selected exactly a chunk at a time
    (:func:`pipeline.recon.surface.percentiles`)."""
    n = surface.count
    return np.stack([surface_mod.percentiles(lambda k=k: (c[0][:, k] for c in surface.chunks(("xyz",))), [0.5, 99.5],
                                             n) for k in (0, 1)], axis=1)


def _placed(box: np.ndarray | None, grid: GridParams, p: ReconstructParams) -> GridSpec:
    """:func:`place_grid` on the surface's percentile ``box`` ``(2, 2)`` (None: the centre is pinned)."""
    n = lattice_ratio(grid, p)
    v, s = p.voxel_size_m, grid.cell_size_m
    rows, cols = grid.rows, grid.cols
    if grid.centre_xy is not None:
        centre = np.asarray(grid.centre_xy, np.float64)
    else:
        lo, hi = box
        centre = (lo + hi) / 2.0
        if grid.extent == "grow":
            need = np.ceil((hi - lo + 2 * _GROW_MARGIN_M) / s).astype(np.int64)  # cells along x, y
            if need[0] > cols:
                cols = int(-(-need[0] // TILE) * TILE)
            if need[1] > rows:
                rows = int(-(-need[1] // TILE) * TILE)
            if max(rows, cols) > _GROW_MAX_CELLS:
                raise ConfigError(
                    f"grid.extent: the surface spans {(hi - lo)[0]:.0f} x {(hi - lo)[1]:.0f} m, a grid of "
                    f"{rows} x {cols} cells (more than {_GROW_MAX_CELLS} on a side): a wrong pose or depth scale; "
                    "set grid.extent: fixed with grid.rows/cols to map part of it")
    off = 0.0 if n % 2 == 0 else 0.5  # cell centre = origin + (j + 1/2) n v must be k v
    x0 = v * (np.round((centre[0] - cols * s / 2.0) / v - off) + off)
    y0 = v * (np.round((centre[1] + rows * s / 2.0) / v - off) + off)
    return GridSpec(rows, cols, s, (float(x0), float(y0)))


# ----------------------------------------------------------------------------- grids

def navigable_mask(free: np.ndarray, occupied: np.ndarray, cell_size_m: float, robot_radius_m: float) -> np.ndarray:
    """``(rows, cols)`` bool: free cells whose centre is farther than the radius from every occupied centre."""
    if not occupied.any():
        return free.copy()
    dist_m = distance_transform_edt(~occupied) * cell_size_m
    return free & (dist_m > robot_radius_m)


def enclosed_unknown(occupied: np.ndarray, free: np.ndarray, cell_size_m: float, max_area_m2: float) -> np.ndarray:
    """Unknown regions (4-connected) walled in by occupied cells only: the unseen insides of solids.

    A region touching a free cell or the grid border, or larger than ``max_area_m2``, stays unknown.
    """
    unknown = ~occupied & ~free
    labels, n = label(unknown)
    if n == 0:
        return np.zeros_like(occupied)
    open_ids = np.unique(labels[binary_dilation(free) & unknown])
    border = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    sizes = np.bincount(labels.ravel(), minlength=n + 1) * cell_size_m**2
    keep = sizes <= max_area_m2
    keep[open_ids] = False
    keep[border] = False
    keep[0] = False
    return keep[labels]


def building_mask(occupied: np.ndarray, free: np.ndarray, cell_size_m: float, closing_m: float) -> np.ndarray:
    """``(rows, cols)`` bool: the observed area closed by a disc of radius ``closing_m``, holes filled.

    Walls hidden behind furniture are never seen, so the unknown inside of a wardrobe standing
    against an outer wall touches the unknown world outside; closing the observed area bridges such
    gaps (up to ``2 * closing_m`` wide) and separates the building's inside from the outside.
    Computed with two distance transforms (a disc closing) and a hole fill.
    """
    r = closing_m / cell_size_m
    pad = int(np.ceil(r)) + 1  # room around the grid, so the erosion sees the unobserved world past its edge
    seen = np.pad(occupied | free, pad)
    dilated = distance_transform_edt(~seen) <= r
    closed = distance_transform_edt(dilated) > r
    return binary_fill_holes(closed | seen)[pad:-pad, pad:-pad]


def hidden_solid(occupied: np.ndarray, free: np.ndarray, cell_size_m: float, max_dist_m: float,
                 closing_m: float = 1.0, max_region_m2: float = np.inf) -> np.ndarray:
    """Unknown cells inside the building nearer to an occupied cell than to any free cell, within ``max_dist_m``.

    The back of a wardrobe seen only from the front is never observed; its cells lie behind the
    observed face, closer to it than to the free floor in front. Unknown cells outside the building
    (:func:`building_mask` with ``closing_m``) are left alone, and so are unknown regions (4-connected)
    larger than ``max_region_m2``: a room never entered is not the back of a piece of furniture.
    ``max_dist_m = 0`` turns this off.
    """
    if max_dist_m <= 0 or not occupied.any() or not free.any():
        return np.zeros_like(occupied)
    unknown = ~occupied & ~free & building_mask(occupied, free, cell_size_m, closing_m)
    labels, n = label(unknown)
    small = np.bincount(labels.ravel(), minlength=n + 1) * cell_size_m**2 <= max_region_m2
    small[0] = False
    d_occ = distance_transform_edt(~occupied) * cell_size_m
    d_free = distance_transform_edt(~free) * cell_size_m
    return small[labels] & (d_occ < d_free) & (d_occ <= max_dist_m)


@dataclass
class Columns:
    """What the cell-centre voxel columns show (:func:`column_occupancy`), ``(rows, cols)`` arrays."""

    occupied: np.ndarray  # bool: solid in the obstacle band (a negative voxel, or a solid top)
    floor_seen: np.ndarray  # bool: the floor was observed at the centre
    low_air: np.ndarray  # bool: air observed low above the floor (below hidden_free_max_height_m)
    solid_z: np.ndarray  # (rows, cols, 2) float32: lowest / highest solid evidence, m above the floor; NaN none
    tops_only: np.ndarray  # bool: occupied by a solid top alone (solid_tops), no voxel behind a surface


def column_occupancy(grid: GridSpec, floor_z: float, voxels: Iterable[tuple[np.ndarray, np.ndarray]],
                     p: ReconstructParams, *, whole_columns: bool = False) -> Columns:
    """The cell-centre columns of observed voxels (see the module doc and :class:`Columns`).

    ``occupied``: a voxel of the cell-centre column in the obstacle band lies behind a surface
    (negative TSDF), or the column shows the top of a solid seen only from above
    (:func:`solid_tops`). ``low_air``: a voxel of the cell-centre column between
    ``obstacle_min_height_m`` and ``hidden_free_max_height_m`` was observed in front of a surface
    (positive TSDF): the space low above the floor there was seen empty, so the cell is no unseen
    inside of furniture.

    The chunks of ``voxels`` may split a column: its voxels are gathered across them. ``whole_columns``: each chunk
    holds every voxel of the lattice columns it touches (a fusion tile's voxels), so the solid tops are found chunk
    by chunk (the same ones: :func:`solid_tops` looks only along a column), memory bounded by a chunk.
    """
    v = p.voxel_size_m
    n = int(round(grid.cell_size_m / v))
    # Lattice index of the centre column of cell (0, 0); centres repeat every n voxels.
    k0 = np.round(np.array([grid.origin_xy[0] / v + 0.5 * n, grid.origin_xy[1] / v - 0.5 * n])).astype(np.int64)
    # The floor is seen where a lattice point lies behind it or within half a voxel in front of it;
    # an obstacle needs a lattice point strictly behind a surface (a cell centre inside the solid).
    touch = 0.5 * v / p.sdf_trunc_m
    # Band levels (voxel z index relative to the floor) with the margins solid_tops looks into:
    # one level above, a slab's unobserved gap and the voxel under it below.
    max_gap = max(1, int(round(_SLAB_MAX_M / v)))
    lo = int(np.ceil(p.obstacle_min_height_m / v - 1e-9)) - (max_gap + 1)
    hi = int(np.floor(p.obstacle_max_height_m / v + 1e-9)) + 1
    levels = hi - lo + 1
    cells = grid.rows * grid.cols
    floor_seen = np.zeros(cells, dtype=bool)
    low_air = np.zeros(cells, dtype=bool)
    solid_lo = np.full(cells, levels, dtype=np.int64)  # level index, ``levels`` = none
    solid_hi = np.full(cells, -1, dtype=np.int64)
    top_cells = np.zeros(cells, dtype=bool)
    keys, values, found = [], [], []
    for lattice, tsdf in voxels:
        centre = ((lattice[:, 0] - k0[0]) % n == 0) & ((lattice[:, 1] - k0[1]) % n == 0)
        lat, t = lattice[centre], tsdf[centre]
        rc = grid.world_to_cell(lat[:, :2].astype(np.float64) * v)
        inside = grid.inside(rc)
        cell = np.where(inside, rc[:, 0] * grid.cols + rc[:, 1], 0)
        z = lat[:, 2].astype(np.float64) * v - floor_z
        level = np.round(z / v).astype(np.int64)
        band = inside & (z >= p.obstacle_min_height_m)
        occ = band & (t < 0) & (z <= p.obstacle_max_height_m)
        np.minimum.at(solid_lo, cell[occ], level[occ] - lo)
        np.maximum.at(solid_hi, cell[occ], level[occ] - lo)
        low_air[cell[band & (t > 0) & (z <= p.hidden_free_max_height_m)]] = True
        floor_seen[cell[inside & (t < touch) & (np.abs(z) <= p.floor_tolerance_m)]] = True
        near = inside & (level >= lo) & (level <= hi)
        keys.append(cell[near] * levels + (level[near] - lo))
        values.append(t[near])
        if whole_columns:
            found.append(solid_tops(keys.pop(), values.pop(), levels, first=max_gap + 1, last=levels - 2,
                                    max_gap=max_gap))
    behind_surface = solid_hi >= 0
    if keys:
        found.append(solid_tops(np.concatenate(keys), np.concatenate(values), levels, first=max_gap + 1,
                                last=levels - 2, max_gap=max_gap))
    if found:
        tops, slabs = (np.concatenate([f[k] for f in found]) for k in (0, 1))
        tops = np.concatenate([tops, board_slabs(slabs, levels, grid)])
        top_cell, top_level = tops // levels, tops % levels - 1  # the solid lies just below the voxel
        np.minimum.at(solid_lo, top_cell, top_level)
        np.maximum.at(solid_hi, top_cell, top_level)
        top_cells[top_cell] = True
    occupied = solid_hi >= 0
    solid_z = np.full((cells, 2), np.nan, dtype=np.float32)
    solid_z[occupied, 0] = (solid_lo[occupied] + lo) * v
    solid_z[occupied, 1] = (solid_hi[occupied] + lo) * v
    shape = (grid.rows, grid.cols)
    return Columns(occupied.reshape(shape), floor_seen.reshape(shape), low_air.reshape(shape),
                   solid_z.reshape(shape + (2,)), (top_cells & ~behind_surface).reshape(shape))


def solid_tops(key: np.ndarray, tsdf: np.ndarray, levels: int, first: int, last: int, max_gap: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """Keys (``cell * levels + level``) of voxels just above the top of a solid whose inside was never observed.

    Returns ``(tops, slabs)``: the keys of the two signatures below (a key in both is a top);
    slabs still need the patch test of :func:`column_occupancy`.

    ``key = cell * levels + level`` of observed voxels (unique), ``tsdf`` their values; levels
    ``first..last`` are tested (``first > max_gap``). A thin top (a table's 4 cm board, a seat)
    seen only at grazing angles from a camera above it has no observed voxel behind its surface:
    rays reach its inside more than the truncation distance behind the surface, so fusion never
    updates it, and the column test finds no negative voxel. Two signatures mark it:

    - a voxel close in front of a surface (``0 < tsdf < _SOLID_TOP_MAX_TSDF``), the voxel above it
      farther from the surface (``tsdf`` rising by at least ``_SOLID_TOP_MIN_RISE``: the surface lies
      below, not beside), and below it a voxel never observed or behind a surface;
    - a slab: a voxel seen in front of a surface, then 1 to ``max_gap`` voxels never observed, then a
      voxel seen in front of a surface again (the space above and under the board was seen, the
      board itself never: views so grazing that even the voxel above it reads far from a surface).

    The floor is excluded by the band; a vertical face (``tsdf`` constant along the column) and the
    unseen space behind furniture (a tall unobserved run) never qualify.
    """
    order = np.argsort(key, kind="stable")
    key, tsdf = key[order], tsdf[order]
    level = key % levels
    cand = np.flatnonzero((tsdf > 0) & (level >= first) & (level <= last))
    if cand.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)

    def lookup(k):
        i = np.minimum(np.searchsorted(key, k), key.size - 1)
        found = key[i] == k
        return found, np.where(found, tsdf[i], np.nan)

    k, t = key[cand], tsdf[cand]
    seen_above, t_above = lookup(k + 1)
    seen_below, t_below = lookup(k - 1)
    top = ((t < _SOLID_TOP_MAX_TSDF) & seen_above & (t_above >= t + _SOLID_TOP_MIN_RISE)
           & (~seen_below | (t_below < 0)))
    slab = np.zeros_like(top)
    unseen_run = ~seen_below
    for gap in range(1, max_gap + 1):
        seen, t_under = lookup(k - gap - 1)
        slab |= unseen_run & seen & (t_under > 0)
        unseen_run &= ~seen
    return k[top], k[slab & ~top]


def board_slabs(slabs: np.ndarray, levels: int, grid: GridSpec) -> np.ndarray:
    """The slab keys (:func:`solid_tops`) that form a board: a flat patch of at least ``_SLAB_MIN_AREA_M2``.

    A board is horizontal, so its slabs sit at one level (one voxel of slack); a lone unobserved
    gap in seen free space, or gaps at scattered heights, are no board.
    """
    cell, level = slabs // levels, slabs % levels
    keep = np.zeros(len(slabs), dtype=bool)
    for at in np.unique(level):
        near = np.abs(level - at) <= 1
        mask = np.zeros(grid.rows * grid.cols, dtype=bool)
        mask[cell[near]] = True
        labels, n = label(mask.reshape(grid.rows, grid.cols), structure=np.ones((3, 3), bool))
        big = np.bincount(labels.ravel(), minlength=n + 1) * grid.cell_size_m**2 >= _SLAB_MIN_AREA_M2
        big[0] = False
        here = level == at
        keep[here] |= big[labels.ravel()[cell[here]]]
    return slabs[keep]


def placed_grid(surface: Surface, T_world_camera: dict[int, np.ndarray], grid_params: GridParams,
                p: ReconstructParams, *, source: str = "frames") -> GridSpec:
    """The grid every floor of one reconstruction shares (:func:`place_grid`), checked to hold every camera.

    ``surface``: the surface points; ``T_world_camera``: frame index -> pose used. Raises
    :class:`StageError` for an empty scene and :class:`InputDataError` naming the first camera outside the grid.
    """
    if surface.count == 0:
        raise StageError(f"{source}: the fused volume has no surface (empty scene, or depth never observed "
                         f"{p.min_weight:g}+ times at the same place: reconstruct.min_weight)")
    grid = _placed(None if grid_params.centre_xy is not None else surface_box(surface), grid_params, p)
    cam_idx = np.array(sorted(T_world_camera), dtype=np.int64)
    cam = np.stack([T_world_camera[i][:3, 3] for i in cam_idx])
    cam_rc = grid.world_to_cell(cam[:, :2])
    out_cam = np.flatnonzero(~grid.inside(cam_rc))
    if out_cam.size:
        i = int(cam_idx[out_cam[0]])
        x, y = cam[out_cam[0], :2]
        x0, x1, y0, y1 = grid.extent_xy
        raise InputDataError(
            f"camera at ({x:.2f}, {y:.2f}) m lies outside the top-down grid "
            f"x [{x0:.2f}, {x1:.2f}], y [{y0:.2f}, {y1:.2f}] ({out_cam.size} cameras outside)",
            path=source, field="pose", frame=i,
            expected="poses within the mapped area; a wrong pose, or a larger grid (grid.rows/cols/cell_size_m)",
        )
    return grid


def floor_grids(grid: GridSpec, floor_z: float, surface: Surface, voxels: Iterable[tuple[np.ndarray, np.ndarray]],
                p: ReconstructParams, *, band: tuple[float, float] | None = None, whole_columns: bool = False,
                floor_points: int = 0, source: str = "frames", floor_name: str | None = None,
                void: np.ndarray | None = None) -> Grids:
    """All grids of one floor at world height ``floor_z`` on ``grid``.

    ``surface``: the surface points, of which the floor's ``band`` ``(lo, hi)`` of world heights
    (:func:`pipeline.recon.store.floor_bands`; None: all of them, a single floor) is read a chunk at a time;
    ``voxels``: :func:`pipeline.recon.tsdf.iter_voxels` (the columns read only the heights near this floor;
    ``whole_columns``: see :func:`column_occupancy`). Raises :class:`StageError` when more than ``max_outside_fraction`` of the
    surface falls outside the grid or no free floor cell was seen (``floor_name`` names the floor of a building).
    ``floor_points``: the surface points the floor height rests on (a figure of ``stats``).
    ``void``: ``(rows, cols)`` bool, cells where the floor has no floor: the stairwell over a flight from the floor
    below (:meth:`pipeline.recon.stairs.Flight.footprint`). The rules that infer an unseen solid standing on the
    floor (the gap closing, :func:`enclosed_unknown`, :func:`hidden_solid`) leave it alone: the band there is
    unobserved because it is the air over the stairs (a TSDF keeps only voxels near a surface), not the inside of
    furniture. What was observed there (a railing, a wall) counts as everywhere.
    """
    where = f"{source}: {floor_name}" if floor_name else source
    inferable = np.ones((grid.rows, grid.cols), bool) if void is None else ~void
    columns = column_occupancy(grid, floor_z, voxels, p, whole_columns=whole_columns)
    floor_seen, low_air = columns.floor_seen, columns.low_air
    counts = np.zeros(grid.rows * grid.cols, np.int64)
    top, n_points = TopSurface(grid, floor_z, p), 0
    for xyz, normals, colors in band_chunks(surface, band):
        counts += surface_counts(grid, floor_z, xyz, normals, p)
        top.add(xyz, colors)
        n_points += len(xyz)
    occupied = columns.occupied | (counts >= p.surface_min_points).reshape(grid.rows, grid.cols)
    height, color, outside = top.result()
    outside_fraction = outside / n_points
    if outside_fraction > p.max_outside_fraction:
        raise StageError(
            f"{where}: {outside} of {n_points} surface points ({outside_fraction:.1%}) fall outside the "
            f"{grid.rows}x{grid.cols} grid at {grid.cell_size_m} m (expected at most "
            f"{p.max_outside_fraction:.1%}: enlarge grid.rows/cols or grid.cell_size_m)"
        )
    # Close one-cell gaps in sparsely sampled tops (grazing views), but never over observed floor.
    occupied |= binary_closing(occupied, structure=np.ones((3, 3), bool)) & ~floor_seen & inferable
    occupied |= enclosed_unknown(occupied, floor_seen & ~occupied, grid.cell_size_m, p.fill_enclosed_max_m2) & inferable
    hidden = hidden_solid(occupied, floor_seen & ~occupied, grid.cell_size_m, p.hidden_solid_max_m,
                          p.building_closing_m, p.fill_enclosed_max_m2) & ~low_air & inferable
    occupied |= hidden
    # Last, so that no rule above fills a cell an observed face passes in front of.
    cleared = faces_cleared(grid, floor_z, surface, band, occupied, columns.solid_z, p)
    occupied &= ~cleared
    free = floor_seen & ~occupied
    occupancy = np.full(occupied.shape, UNKNOWN, np.uint8)
    occupancy[free] = FREE
    occupancy[occupied] = OCCUPIED
    navigable = navigable_mask(free, occupied, grid.cell_size_m, p.robot_radius_m)
    if not free.any():
        raise StageError(f"{where}: no free floor cell was observed (floor_z {floor_z:.3f} m); "
                         "the top-down map would be empty")
    stats = {
        "floor_z_m": round(floor_z, 4),
        "floor_points": floor_points,
        "cells_free": int(free.sum()),
        "cells_occupied": int(occupied.sum()),
        "cells_unknown": int((occupancy == UNKNOWN).sum()),
        "cells_navigable": int(navigable.sum()),
        "cells_inferred_occupied": int(hidden.sum()),
        "cells_occupied_by_tops": int((columns.tops_only & occupied).sum()),
        "cells_cleared_in_front_of_faces": int(cleared.sum()),
        "points_outside_grid": outside,
        "points_outside_fraction": round(float(outside_fraction), 6),
    }
    return Grids(grid, floor_z, occupancy, navigable, color, height, stats)


def with_solid(grids: Grids, solid: np.ndarray, p: ReconstructParams) -> Grids:
    """``grids`` with the unknown cells of ``solid`` ``(rows, cols)`` bool occupied and navigable recomputed: a stair
    flight on the floor it rises from (its inside is never seen; where the floor under it was seen, it stays free)."""
    add = solid & (grids.occupancy == UNKNOWN)
    if not add.any():
        return grids
    occupancy = grids.occupancy.copy()
    occupancy[add] = OCCUPIED
    navigable = navigable_mask(occupancy == FREE, occupancy == OCCUPIED, grids.grid.cell_size_m, p.robot_radius_m)
    stats = {**grids.stats, "cells_occupied": int((occupancy == OCCUPIED).sum()),
             "cells_unknown": int((occupancy == UNKNOWN).sum()), "cells_navigable": int(navigable.sum()),
             "cells_occupied_by_stairs": int(grids.stats.get("cells_occupied_by_stairs", 0)) + int(add.sum())}
    return Grids(grids.grid, grids.floor_z, occupancy, navigable, grids.color, grids.height, stats)
