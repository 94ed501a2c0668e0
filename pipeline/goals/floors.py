"""The floors of a building as the goals stage sees them: per floor its grid, line-of-sight walls, footprint raster,
planner and goal regions; the building's planner over every floor; the floor the recording starts on.

A goal lies on the floor of its objects. Its descriptive, corrective and landmark feedback is made among that
floor's objects and walls, its region is cut on that floor's navigable grid (line of sight from that floor's
camera height), and its procedural feedback walks from the recording's start, on the start's floor, over the
stairs (:class:`pipeline.nav.building.BuildingPlanner`). A single-floor scene has none of this.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from pipeline.geometry import GridSpec, Intrinsics
from pipeline.goals.objects import ObjectSet, rasterize_polygons


@dataclass
class FloorParts:
    """One floor: its ``grid``, ``walls`` ``(rows, cols)`` bool (block line of sight), ``object_index`` ``(rows,
    cols)`` int32 (1 + index into the scene's objects, its own floor's only), ``planner`` and ``goal_region``
    (``(members, object_index, keys) -> (rows, cols)`` bool)."""

    grid: GridSpec
    walls: np.ndarray
    object_index: np.ndarray
    planner: Any
    goal_region: Callable[..., np.ndarray]


@dataclass
class Building:
    floors: dict[int, FloorParts]
    planner: Any  # pipeline.nav.building.BuildingPlanner
    start_floor: int = 0


def floor_object_index(objset: ObjectSet, floor: int, grid: GridSpec) -> np.ndarray:
    """``(rows, cols)`` int32: the footprints of ``floor``'s objects on ``grid``, as 1 + index into ``objset.objects``
    (the scene-wide index every reader of ``object_index`` uses)."""
    on = [i for i, o in enumerate(objset.objects) if o.floor == floor]
    if not on:
        return np.zeros((grid.rows, grid.cols), np.int32)
    local = rasterize_polygons([np.asarray(objset.objects[i].footprint) for i in on], grid)
    lookup = np.concatenate([[0], np.asarray(on, np.int64) + 1]).astype(np.int32)
    return lookup[local]


START_SNAP_MIN_M = 1.0  # a start pose moves at least this far onto the navigable grid, whatever the camera


def blind_radius_m(T_world_camera: np.ndarray, intrinsics: Intrinsics, floor_z: float) -> float:
    """How far from its feet a camera at ``T_world_camera`` (OpenCV axes, world z up) first sees the floor at
    ``floor_z``: along its image's lowest row, through the centre column, where that ray meets the floor (inf when
    the ray does not look down). A pose on a cell never seen as floor is at most this far from one that was."""
    ray = np.array([0.0, (intrinsics.height - intrinsics.cy) / intrinsics.fy, 1.0])
    d = np.asarray(T_world_camera, np.float64)[:3, :3] @ ray
    height = float(T_world_camera[2, 3]) - floor_z
    if d[2] >= 0 or height <= 0:
        return float("inf")
    return height * float(np.hypot(d[0], d[1])) / float(-d[2])


def walkable_start(pose: tuple[float, float, float] | None, navigable: np.ndarray, grid: GridSpec,
                   max_m: float = 1.0) -> tuple[tuple[float, float, float] | None, float]:
    """The recording's start pose moved onto the navigable grid: ``(pose, metres moved)``. A camera that looks ahead
    never sees the floor it stands on until it has moved away, so the first pose's cell can be unknown; the robot
    stood there, so the nearest navigable cell within ``max_m`` is where a route from it starts (yaw kept). The pose
    as it was when its cell is navigable or none is that near (0 moved)."""
    from scipy import ndimage

    if pose is None:
        return None, 0.0
    rc = grid.world_to_cell(np.asarray(pose[:2], np.float64))
    nav = np.asarray(navigable, bool)
    if not grid.inside(rc) or nav[rc[0], rc[1]] or not nav.any():
        return pose, 0.0
    pad = int(np.ceil(max_m / grid.cell_size_m)) + 1
    r0, c0 = max(int(rc[0]) - pad, 0), max(int(rc[1]) - pad, 0)
    window = nav[r0:int(rc[0]) + pad + 1, c0:int(rc[1]) + pad + 1]
    if not window.any():
        return pose, 0.0
    dist, (ri, ci) = ndimage.distance_transform_edt(~window, return_indices=True)
    lr, lc = int(rc[0]) - r0, int(rc[1]) - c0
    if dist[lr, lc] * grid.cell_size_m > max_m:
        return pose, 0.0
    x, y = grid.cell_to_world(np.array([ri[lr, lc] + r0, ci[lr, lc] + c0]))
    moved = float(np.hypot(x - pose[0], y - pose[1]))
    return (float(x), float(y), float(pose[2])), moved


def floors_of_objects(objset: ObjectSet, floors: int, where: str) -> None:
    """Refuse objects (or rooms) on a floor the reconstruction does not have, naming them."""
    from pipeline.errors import InputDataError

    bad = [o.key for o in objset.objects if o.floor >= floors] + [r.id for r in objset.rooms if r.floor >= floors]
    if bad:
        raise InputDataError(f"{bad[:5]} lie on floors the reconstruction does not have (it found {floors})",
                             path=where, field="floor", expected=f"a floor id 0..{floors - 1}")
