"""North-up top-down pictures of a ground-truth scene (rooms, walls, objects, labels, scale bar)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.pictures import write_png
from pipeline.scene_gt import GTScene

ROOM_TINTS = {
    "living room": (246, 236, 214), "kitchen": (226, 240, 226), "bathroom": (220, 236, 246),
    "bedroom": (244, 226, 232), "office": (236, 232, 246), "hallway": (236, 236, 236),
}


def scene_grid(gt: GTScene, cell_size_m: float, margin_m: float = 0.5) -> GridSpec:
    """A grid covering the scene's rooms plus ``margin_m`` on every side."""
    x0, x1, y0, y1 = gt.bounds_xy()
    cols = int(np.ceil((x1 - x0 + 2 * margin_m) / cell_size_m))
    rows = int(np.ceil((y1 - y0 + 2 * margin_m) / cell_size_m))
    return GridSpec(rows, cols, cell_size_m, (x0 - margin_m, y1 + margin_m))


def draw_scene_topdown(gt: GTScene, *, px_per_m: float = 50.0, path_xy: np.ndarray | None = None) -> np.ndarray:
    """``(H,W,3)`` uint8 RGB north-up picture of ``gt`` (optionally a trajectory ``(N,2)`` world x, y)."""
    import cv2

    grid = scene_grid(gt, 1.0 / px_per_m, margin_m=0.8)
    img = np.full((grid.rows, grid.cols, 3), 255, dtype=np.uint8)

    def rc(xy):
        return grid.world_to_cell(np.asarray(xy, dtype=np.float64))

    def rect(box_min, box_max, colour, thickness=-1):
        (r0, c0), (r1, c1) = rc(box_max[:2]), rc(box_min[:2])
        cv2.rectangle(img, (int(c1), int(r0)), (int(c0), int(r1)), colour, thickness)

    for room in gt.rooms:
        poly = rc(room.polygon)[:, ::-1].astype(np.int32)
        cv2.fillPoly(img, [poly.reshape(-1, 1, 2)], ROOM_TINTS.get(room.type, (236, 236, 236)))
    for wall in gt.walls:
        if wall.min[2] <= gt.floor_z + 0.1:  # lintels above doorways are not drawn
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
                     path_xy: np.ndarray | None = None) -> Path:
    """Write :func:`draw_scene_topdown` as a PNG at ``path``; returns the path."""
    return write_png(Path(path), draw_scene_topdown(gt, px_per_m=px_per_m, path_xy=path_xy))
