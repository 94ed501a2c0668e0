"""The goal region: where an episode can succeed — ONE definition for routes, episodes and the evaluator.

A goal's region is the set of navigable cells

- whose centre is within ``success_m`` (the paper's 1.5 m) of one of the goal's object footprints
  (Euclidean distance between cell centres, so never farther than ``success_m`` from the footprint
  polygon), and
- from which that object's mass centre is in LINE OF SIGHT on the reconstruction.

Line of sight (:class:`MeshSight`) is mesh ray casting on the RECONSTRUCTED mesh
(``recon_mesh.ply``, open3d ``RaycastingScene``): a ray from the camera above the cell centre
(``camera_height_m`` above the floor) to the mass-centre column at each of ``z_levels`` metres above
the floor (:func:`sight_levels`: half and full height of the object). The column is in sight when
one ray meets no surface before it (within ``tolerance_m``) or first meets a surface inside the
object's own footprint dilated by :data:`OWN_DILATION_CELLS` cells (the object itself). The
evaluator's success rule (:mod:`orion_eval.world`) uses the same test, so a route that ends in the
region with the mass centre inside the 90 deg view is a success.

:func:`goal_region` computes the region of one object; a same_goal group is the union over its
members. A route into a goal is planned once, by :func:`route_to_goal`. :func:`route_target` is the part of the region a planner aims for: per connected part of
the region, cells within ``stop_radius_m`` of the footprint and at least ``margin_cells`` inside the
region's edge (falling back to the margin alone; specks and strips with no such cell are skipped),
so a walk that ends up to half a step off its target still ends inside the region. The reference length ``l`` for SPL is the geodesic distance
to the region itself.

Arrays are ``(rows, cols)`` bool on a :class:`~pipeline.geometry.GridSpec`; world metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import ndimage

from pipeline.geometry import GridSpec

SIGHT_LEVELS = (0.5, 1.0)  # fractions of the object's height sighted on its mass-centre column (1.0 = its top)
OWN_DILATION_CELLS = 2  # a ray first hitting the footprint dilated by this many cells hits the object itself
ROUTE_MARGIN_CELLS = 3  # route targets lie this many cells inside the region's edge (a walk ends <= ~0.15 m off)
SIGHT_METHOD = "mesh ray casting (open3d RaycastingScene on recon_mesh.ply)"

# (origins_xy (N,2), target_xy (2,), z_levels (L,), own (rows, cols) bool) -> (N,) bool
SightFn = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def sight_levels(z_range) -> np.ndarray:
    """``(L,)`` heights above the floor (metres) sighted on an object spanning ``z_range`` = (z0, z1)."""
    z0, z1 = (float(v) for v in z_range)
    return np.array([z0 + f * (z1 - z0) for f in SIGHT_LEVELS])


def own_cells(object_mask: np.ndarray) -> np.ndarray:
    """The object's own cells for line of sight: its footprint dilated by :data:`OWN_DILATION_CELLS`
    (dilated on the footprint's bounding box grown by that many cells and one more, not the whole grid)."""
    obj = np.asarray(object_mask, bool)
    out = np.zeros_like(obj)
    if obj.any():
        win = _window(obj, OWN_DILATION_CELLS + 1)
        out[win] = ndimage.binary_dilation(obj[win], iterations=OWN_DILATION_CELLS)
    return out


def recorded_camera_height(poses: np.ndarray, floor_z: float, default: float = 0.88) -> float:
    """Median camera height above the floor of the recording's ``(N,4,4)`` poses (``default`` without any)."""
    z = np.asarray(poses)[:, 2, 3]
    z = z[np.isfinite(z)]
    return float(np.median(z) - floor_z) if z.size else float(default)


class MeshSight:
    """Line of sight by ray casting a triangle mesh (see the module docstring).

    ``scene`` is an open3d ``RaycastingScene`` holding the reconstructed mesh; ``cam_z`` the world z
    of the camera; ``floor_z`` the world z of the floor.
    """

    def __init__(self, scene, *, cam_z: float, floor_z: float, grid: GridSpec, tolerance_m: float = 0.15):
        import open3d as o3d

        self._o3d = o3d
        self.scene, self.cam_z, self.floor_z, self.grid = scene, float(cam_z), float(floor_z), grid
        self.tolerance = float(tolerance_m)

    @classmethod
    def from_mesh(cls, mesh_path, *, floor_z: float, camera_height_m: float, grid: GridSpec,
                  tolerance_m: float = 0.15) -> "MeshSight":
        import open3d as o3d

        from pipeline.recon.store import read_mesh_geometry

        v, t = read_mesh_geometry(mesh_path)  # positions and triangles only: a large floor's mesh is GBs in full
        scene = o3d.t.geometry.RaycastingScene()
        if len(t):
            scene.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(t))
        return cls(scene, cam_z=float(floor_z) + float(camera_height_m), floor_z=floor_z, grid=grid,
                   tolerance_m=tolerance_m)

    def __call__(self, origins_xy: np.ndarray, target_xy, z_levels, own: np.ndarray, *, every: bool = False
                 ) -> np.ndarray:
        """``(N,)`` bool: the column at ``target_xy`` is in sight from each of ``origins_xy`` ``(N,2)`` at one
        (``every``: each) of ``z_levels`` (metres above the floor); ``own`` = :func:`own_cells` of the object."""
        o = np.asarray(origins_xy, np.float64).reshape(-1, 2)
        out = np.full(len(o), bool(every))
        if not len(o):
            return out
        origins = np.column_stack([o, np.full(len(o), self.cam_z)])
        for z in np.asarray(z_levels, np.float64).reshape(-1):
            target = np.array([float(target_xy[0]), float(target_xy[1]), self.floor_z + float(z)])
            d = target[None] - origins
            length = np.linalg.norm(d, axis=1)
            dirs = d / np.maximum(length, 1e-9)[:, None]
            rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
            t = self.scene.cast_rays(self._o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
            hit = np.isfinite(t)
            clear = ~hit | (t >= length - self.tolerance)
            p = origins[:, :2] + dirs[:, :2] * np.where(hit, t, 0.0)[:, None]
            rc = self.grid.world_to_cell(p)
            inside = self.grid.inside(rc)
            on_own = np.zeros(len(o), bool)
            on_own[inside] = np.asarray(own, bool)[rc[inside, 0], rc[inside, 1]]
            seen = clear | (hit & on_own)
            out = (out & seen) if every else (out | seen)
        return out


def goal_region(navigable: np.ndarray, object_mask: np.ndarray, grid: GridSpec, center_xy, z_levels,
                sight: SightFn, *, success_m: float = 1.5) -> np.ndarray:
    """``(rows, cols)`` bool: navigable cells within ``success_m`` of ``object_mask`` from which the object's
    mass centre ``center_xy`` (world) is in sight at one of ``z_levels`` (see the module docstring)."""
    nav = np.asarray(navigable, bool)
    obj = np.asarray(object_mask, bool)
    out = np.zeros(nav.shape, bool)
    if not obj.any():
        return out
    # distance transform on the object's bounding box grown by the success distance (not the whole grid)
    win = _window(obj, region_pad_cells(grid, success_m))
    near = nav[win] & (ndimage.distance_transform_edt(~obj[win]) * grid.cell_size_m <= success_m + 1e-9)
    cr, cc2 = np.nonzero(near)
    if not len(cr):
        return out
    cells = np.stack([cr + win[0].start, cc2 + win[1].start], axis=1)
    seen = np.asarray(sight(grid.cell_to_world(cells), np.asarray(center_xy, np.float64), z_levels, own_cells(obj)),
                      bool)
    out[cells[seen, 0], cells[seen, 1]] = True
    return out


def region_pad_cells(grid: GridSpec, success_m: float) -> int:
    """Cells a goal region reaches beyond its object's footprint (its bounding box grown by this holds it)."""
    return int(np.ceil(success_m / grid.cell_size_m)) + 1


def sight_window(object_mask: np.ndarray, grid: GridSpec, center_xy, *, success_m: float = 1.5
                 ) -> tuple[float, float, float, float] | None:
    """``(x0, y0, x1, y1)`` world metres holding every line-of-sight ray :func:`goal_region` casts for the object:
    the centres of the cells within :func:`region_pad_cells` of its footprint's bounding box, and its mass centre
    ``center_xy``. None when the mask is empty."""
    obj = np.asarray(object_mask, bool)
    if not obj.any():
        return None
    win = _window(obj, region_pad_cells(grid, success_m))
    corners = grid.cell_to_world(np.array([[win[0].start, win[1].start], [win[0].stop - 1, win[1].stop - 1]]))
    pts = np.vstack([corners, np.asarray(center_xy, np.float64).reshape(1, 2)])
    return (*map(float, pts.min(axis=0)), *map(float, pts.max(axis=0)))


def route_target(region: np.ndarray, object_mask: np.ndarray, grid: GridSpec, *, stop_radius_m: float,
                 margin_cells: int = ROUTE_MARGIN_CELLS) -> np.ndarray:
    """The cells of ``region`` a route aims for; empty only when the region is.

    Per connected part of the region (8-connected): its cells within ``stop_radius_m`` of the footprint
    and at least ``margin_cells`` inside the region's edge, else its cells that far inside. Parts with
    no cell that far inside (specks seen through a gap, thin strips) are no target unless no part has
    one; then the whole region is the target.
    """
    full = np.asarray(region, bool)
    if not full.any():
        return full.copy()
    # work on the bounding box of the region and the object plus a margin: the same labels, erosion and
    # distances (every object cell is inside it), on a few thousand cells instead of the whole grid
    obj_full = np.asarray(object_mask, bool)
    win = _window(full | obj_full, margin_cells + 2)
    region, obj = full[win], obj_full[win]
    lab, n = ndimage.label(region, structure=np.ones((3, 3), bool))
    inner = ndimage.binary_erosion(region, iterations=margin_cells) if margin_cells > 0 else region
    close = inner & (ndimage.distance_transform_edt(~obj) * grid.cell_size_m <= stop_radius_m + 1e-9) \
        if obj.any() else inner
    out = np.zeros_like(region)
    done = np.zeros(n + 1, bool)
    for cand in (close, inner):
        has = np.zeros(n + 1, bool)
        has[np.unique(lab[cand])] = True
        has[0] = False
        take = has & ~done
        out |= cand & take[lab]
        done |= take
    if not out.any():
        return full.copy()
    result = np.zeros_like(full)
    result[win] = out
    return result


def _window(mask: np.ndarray, pad: int) -> tuple[slice, slice]:
    """The bounding box of ``mask``'s True cells grown by ``pad`` cells (clipped to the grid)."""
    rr, cc = np.nonzero(mask)
    return (slice(max(int(rr.min()) - pad, 0), min(int(rr.max()) + pad + 1, mask.shape[0])),
            slice(max(int(cc.min()) - pad, 0), min(int(cc.max()) + pad + 1, mask.shape[1])))


def route_aims(region: np.ndarray, object_mask: np.ndarray, grid: GridSpec, *, stop_radius_m: float
               ) -> list[tuple[str, np.ndarray]]:
    """``[(name, (rows, cols) bool)]``: what a route into ``region`` aims for, in order — its
    :func:`route_target` with :data:`ROUTE_MARGIN_CELLS`, then with smaller margins (regions whose
    reachable parts are narrow), then the region itself; identical masks are listed once. A planner
    takes the first it can reach (the routes stage: the first whose replay verifies)."""
    out: list[tuple[str, np.ndarray]] = []
    for m in range(ROUTE_MARGIN_CELLS, 0, -1):
        t = route_target(region, object_mask, grid, stop_radius_m=stop_radius_m, margin_cells=m)
        if not any(np.array_equal(t, o) for _, o in out):
            out.append(("target" if m == ROUTE_MARGIN_CELLS else f"target{m}", t))
    if not any(np.array_equal(np.asarray(region, bool), o) for _, o in out):
        out.append(("region", np.asarray(region, bool)))
    return out


def group_region(navigable: np.ndarray, object_index: np.ndarray, object_keys: list[str], members, objects,
                 grid: GridSpec, sight: SightFn, *, success_m: float = 1.5) -> np.ndarray:
    """``(rows, cols)`` bool goal region of a same_goal group: the union of :func:`goal_region` over
    ``members`` (object keys). ``object_index`` ``(rows, cols)`` int: 1 + index into ``object_keys``;
    ``objects`` maps a key to a record with ``mass_center`` (world xy) and ``z_range`` (metres above
    the floor). The routes stage and the goals stage's procedural feedback both call this."""
    region = np.zeros(np.asarray(navigable).shape, bool)
    for k in members:
        o = objects[k]
        region |= goal_region(navigable, object_index == object_keys.index(k) + 1, grid, o.mass_center,
                              sight_levels(o.z_range), sight, success_m=success_m)
    return region


@dataclass(frozen=True)
class GoalTargets:
    """What a route into one goal aims for, computed once per goal: the ``region`` ``(rows, cols)`` bool, its
    ``inner`` cells (2 cells in, by erosion: a walk ending there ends well inside) and its :func:`route_aims`."""

    region: np.ndarray
    inner: np.ndarray
    aims: list[tuple[str, np.ndarray]]

    @classmethod
    def of(cls, region: np.ndarray, object_mask: np.ndarray, grid: GridSpec, *, stop_radius_m: float
           ) -> GoalTargets:
        region = np.asarray(region, bool)
        aims = route_aims(region, object_mask, grid, stop_radius_m=stop_radius_m) if region.any() else []
        return cls(region, ndimage.binary_erosion(region, iterations=2), aims)


# (route) -> (x, y) world metres where walking the route's actions from its start pose ends
WalkEnd = Callable[[object], np.ndarray]


def route_to_goal(planner, pose, targets: GoalTargets, *, key, face_xy, walk_end: WalkEnd | None = None):
    """THE route from ``pose`` (x, y, yaw) into a goal region — the one the goals stage's procedural feedback
    says, the evaluator's simulated user describes and the annotation workbench previews.

    Tries the goal's :func:`route_aims` in order (route target, narrower margins, the region) and keeps the
    first whose walk ends in ``targets.inner``, else the first ending in the region, else the first reachable;
    the walk finishes inside the region and faces the nearest of ``face_xy`` ``(K, 2)``. ``planner`` plans to
    explicit cells (:meth:`pipeline.nav.actions.RoutePlanner.route_into`, or the evaluator's planner);
    ``walk_end`` walks a route (default: :func:`pipeline.nav.verify.replay` on the planner's grid; the
    evaluator walks it in its world). None when the region is empty or unreachable."""
    if not targets.aims:
        return None
    grid = planner.grid
    walk_end = walk_end or _replayed_end(planner, pose)
    best, best_rank = None, -1
    for aim, mask in targets.aims:
        route = planner.route_into(pose, mask, key=(key, aim), face_xy=face_xy, end_mask=targets.region)
        if route is None:
            continue
        rc = grid.world_to_cell(np.asarray(walk_end(route), np.float64))
        inside = grid.inside(rc)
        rank = 2 if inside and targets.inner[rc[0], rc[1]] else int(bool(inside and targets.region[rc[0], rc[1]]))
        if rank == 2:
            return route
        if rank > best_rank:
            best, best_rank = route, rank
    return best


def _replayed_end(planner, pose) -> WalkEnd:
    """Where a route's actions end, replayed from ``pose`` on the planner's navigable grid."""
    from pipeline.nav.verify import replay

    s = planner.settings

    def end(route) -> np.ndarray:
        res = replay(route.actions, pose, planner.navigable, planner.grid, [], step_m=s.step_m, turn_deg=s.turn_deg)
        return np.array(res.final_xyyaw[:2])
    return end
