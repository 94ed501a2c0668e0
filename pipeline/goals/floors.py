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

from pipeline.geometry import GridSpec
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


def floors_of_objects(objset: ObjectSet, floors: int, where: str) -> None:
    """Refuse objects (or rooms) on a floor the reconstruction does not have, naming them."""
    from pipeline.errors import InputDataError

    bad = [o.key for o in objset.objects if o.floor >= floors] + [r.id for r in objset.rooms if r.floor >= floors]
    if bad:
        raise InputDataError(f"{bad[:5]} lie on floors the reconstruction does not have (it found {floors})",
                             path=where, field="floor", expected=f"a floor id 0..{floors - 1}")
