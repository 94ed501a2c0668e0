"""North-up top-down pictures of a ground-truth scene (rooms, walls, objects, labels, scale bar), one floor at a
time, and the ground-truth top-down grids of each floor (:func:`floor_truths`) that a reconstruction's per-floor
grids are scored against."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.pictures import write_png
from pipeline.scene_gt import GTFloor, GTScene

ROOM_TINTS = {
    "living room": (246, 236, 214), "kitchen": (226, 240, 226), "bathroom": (220, 236, 246),
    "bedroom": (244, 226, 232), "office": (236, 232, 246), "hallway": (236, 236, 236),
    "open office": (232, 236, 240), "meeting room": (240, 236, 226),
}
STAIR_COLOUR, OPENING_COLOUR = (150, 108, 72), (96, 96, 120)  # not a grey text or outline can take


@dataclass
class FloorTruth:
    """Ground-truth top-down grids of one floor, each ``(rows, cols)`` bool on the grid they were drawn on.

    ``occupied``: a wall, railing, object part or step overlaps the height band above the floor
    (:meth:`GTScene.occupancy` of :meth:`GTScene.floor_view`); ``free``: inside the floor's rooms (stair
    openings cut out) and not occupied; ``ambiguous``: cells whose label is floating-point rounding
    (:meth:`GTScene.ambiguous`), to leave out of scores; ``stairs``: the cells of the flights joining this
    floor (those rising from it, and the openings of those arriving on it), where a floor's grid meets the
    next one's.
    """

    floor: GTFloor
    occupied: np.ndarray
    free: np.ndarray
    ambiguous: np.ndarray
    stairs: np.ndarray


def _polygon_mask(grid: GridSpec, polygons) -> np.ndarray:
    import cv2

    mask = np.zeros((grid.rows, grid.cols), dtype=np.uint8)
    for polygon in polygons:
        rc = grid.world_to_cell(np.asarray(polygon, dtype=np.float64)).astype(np.int32)
        cv2.fillPoly(mask, [rc[:, ::-1].reshape(-1, 1, 2)], 1)
    return mask.astype(bool)


def floor_truths(gt: GTScene, grid: GridSpec, z_min: float, z_max: float) -> list[FloorTruth]:
    """:class:`FloorTruth` of every floor of ``gt`` on ``grid``, lowest first, for obstacles between ``z_min`` and
    ``z_max`` metres above each floor (reconstruct's obstacle band). A single-floor scene gives one."""
    out = []
    for f in gt.all_floors:
        view = gt.floor_view(f.id)
        occupied = view.occupancy(grid, z_min, z_max)
        stairs = _polygon_mask(grid, [s.footprint for s in gt.stairs if s.lower == f.id]
                               + [s.opening for s in gt.stairs if s.upper == f.id])
        out.append(FloorTruth(floor=f, occupied=occupied, free=view.floor_mask(grid) & ~occupied,
                              ambiguous=view.ambiguous(grid, z_min, z_max), stairs=stairs))
    return out


def scene_grid(gt: GTScene, cell_size_m: float, margin_m: float = 0.5) -> GridSpec:
    """A grid covering the scene's rooms plus ``margin_m`` on every side."""
    x0, x1, y0, y1 = gt.bounds_xy()
    cols = int(np.ceil((x1 - x0 + 2 * margin_m) / cell_size_m))
    rows = int(np.ceil((y1 - y0 + 2 * margin_m) / cell_size_m))
    return GridSpec(rows, cols, cell_size_m, (x0 - margin_m, y1 + margin_m))


def draw_scene_topdown(gt: GTScene, *, px_per_m: float = 50.0, path_xy: np.ndarray | None = None,
                       floor: int = 0) -> np.ndarray:
    """``(H,W,3)`` uint8 RGB north-up picture of floor ``floor`` of ``gt`` (optionally a trajectory ``(N,2)`` world
    x, y); flights rising from the floor are drawn brown with their steps, openings in it dark grey."""
    import cv2

    stairs = gt.stairs
    grid = scene_grid(gt, 1.0 / px_per_m, margin_m=0.8)  # the whole building's: every floor's plan is aligned
    gt = gt.floor_view(floor)
    img = np.full((grid.rows, grid.cols, 3), 255, dtype=np.uint8)

    def rc(xy):
        return grid.world_to_cell(np.asarray(xy, dtype=np.float64))

    def rect(box_min, box_max, colour, thickness=-1):
        (r0, c0), (r1, c1) = rc(box_max[:2]), rc(box_min[:2])
        cv2.rectangle(img, (int(c1), int(r0)), (int(c0), int(r1)), colour, thickness)

    for room in gt.rooms:
        poly = rc(room.polygon)[:, ::-1].astype(np.int32)
        cv2.fillPoly(img, [poly.reshape(-1, 1, 2)], ROOM_TINTS.get(room.type, (236, 236, 236)))
    for stair in (s for s in stairs if s.upper == floor):
        poly = rc(stair.opening)[:, ::-1].astype(np.int32)
        cv2.fillPoly(img, [poly.reshape(-1, 1, 2)], OPENING_COLOUR)
    steps = {(s.min, s.max) for stair in stairs if stair.lower == floor for s in stair.steps}
    for wall in gt.walls:
        if (wall.min, wall.max) in steps:
            rect(wall.min, wall.max, STAIR_COLOUR)
            rect(wall.min, wall.max, (60, 40, 20), 1)
        elif wall.min[2] <= gt.floor_z + 0.1:  # lintels above doorways are not drawn
            rect(wall.min, wall.max, (40, 40, 40))
    for obj in sorted(gt.objects, key=lambda o: o.bbox.max[2]):
        colour = tuple(int(v) for v in obj.color_rgb)
        for part in obj.parts:
            rect(part.min, part.max, colour)
        b = obj.bbox
        rect(b.min, b.max, (60, 60, 60), 1)
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = px_per_m / 120.0
    for obj in gt.objects:
        r, c = rc(obj.center[:2])
        cv2.putText(img, obj.cls, (int(c) - 12, int(r) + 4), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    for room in gt.rooms:
        p = np.asarray(room.polygon)
        r, c = rc([p[:, 0].min() + 0.15, p[:, 1].max() - 0.3])
        cv2.putText(img, room.id, (int(c), int(r)), font, scale * 1.4, (120, 20, 20), 2, cv2.LINE_AA)
    if path_xy is not None and len(path_xy) > 1:
        pts = rc(path_xy)[:, ::-1].astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, (220, 30, 30), 2, cv2.LINE_AA)
        cv2.circle(img, (int(pts[0, 0, 0]), int(pts[0, 0, 1])), 6, (220, 30, 30), -1)
    # Scale bar (1 m) and north arrow in the bottom-left corner.
    y = grid.rows - 15
    cv2.line(img, (15, y), (15 + int(px_per_m), y), (0, 0, 0), 3)
    cv2.putText(img, "1 m", (15, y - 8), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.arrowedLine(img, (grid.cols - 20, 45), (grid.cols - 20, 12), (0, 0, 0), 2, tipLength=0.35)
    cv2.putText(img, "N", (grid.cols - 40, 35), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def render_scene_png(gt: GTScene, path: str | Path, *, px_per_m: float = 50.0,
                     path_xy: np.ndarray | None = None, floor: int = 0) -> Path:
    """Write :func:`draw_scene_topdown` of floor ``floor`` as a PNG at ``path``; returns the path."""
    return write_png(Path(path), draw_scene_topdown(gt, px_per_m=px_per_m, path_xy=path_xy, floor=floor))
