"""Ground truth of a simulated (or annotated) scene: rooms, walls and objects.

Stored as JSON in the raw MCAP log (attachment ``ground_truth.json``) and carried by ingest into
``frames.zarr`` attrs (``ground_truth``). Every solid is a world-axis-aligned box in metres,
z up, floor at ``floor_z``; an object is the union of its part boxes.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.errors import ArtifactError
from pipeline.geometry import GridSpec

GT_FORMAT_VERSION = 1


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Box(_Model):
    """Axis-aligned box ``[min, max]`` in world metres."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    @property
    def center(self) -> np.ndarray:
        return (np.asarray(self.min) + np.asarray(self.max)) / 2.0


class GTRoom(_Model):
    id: str = Field(description="unique room id, e.g. 'bedroom_1'")
    type: str = Field(description="bedroom, living room, kitchen, bathroom, office, hallway, ...")
    polygon: list[tuple[float, float]] = Field(description="floor outline, world x/y metres, counter-clockwise")


class GTObject(_Model):
    id: int = Field(ge=1, description="instance id as written in the instance images (0 = none)")
    cls: str = Field(description="object class, e.g. 'chair'")
    room: str = Field(description="id of the room it stands in")
    parts: list[Box] = Field(min_length=1, description="solid parts; the object is their union")
    color_name: str = Field(description="dominant colour in words, e.g. 'dark green'")
    color_rgb: tuple[int, int, int]
    material: str = Field(description="e.g. 'wood', 'leather', 'metal', 'fabric'")
    size: Literal["big", "small"] = Field(description="big (furniture) or small (on or beside furniture)")

    @property
    def bbox(self) -> Box:
        mins = np.min([p.min for p in self.parts], axis=0)
        maxs = np.max([p.max for p in self.parts], axis=0)
        return Box(min=tuple(mins.tolist()), max=tuple(maxs.tolist()))

    @property
    def center(self) -> np.ndarray:
        return self.bbox.center


class GTScene(_Model):
    format_version: int = GT_FORMAT_VERSION
    name: str
    seed: int
    floor_z: float = 0.0
    wall_height_m: float
    rooms: list[GTRoom]
    walls: list[Box] = Field(description="wall segments (doorways are gaps between them)")
    objects: list[GTObject]

    @classmethod
    def read(cls, data: object, where: str) -> "GTScene":
        """``data`` (a parsed JSON document) as a scene; an ArtifactError names ``where`` and the field that
        does not fit."""
        try:
            return cls.model_validate(data)
        except ValidationError as err:
            first = err.errors()[0]
            field = ".".join(str(p) for p in first["loc"]) or "(root)"
            raise ArtifactError(f"{where}: {field}: {first['msg']} (expected a GTScene document, format version "
                                f"{GT_FORMAT_VERSION})") from None

    def object(self, instance_id: int) -> GTObject:
        for obj in self.objects:
            if obj.id == instance_id:
                return obj
        raise KeyError(f"scene {self.name}: no object with instance id {instance_id}")

    def bounds_xy(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of all rooms."""
        pts = np.concatenate([np.asarray(r.polygon) for r in self.rooms])
        return float(pts[:, 0].min()), float(pts[:, 0].max()), float(pts[:, 1].min()), float(pts[:, 1].max())

    def occupancy(self, grid: GridSpec, z_min: float, z_max: float, *, objects: bool = True) -> np.ndarray:
        """``(rows, cols)`` bool: cells covered by a wall or object part overlapping heights ``[z_min, z_max]``.

        A cell counts when its centre lies inside a box footprint (the rasterisation reconstruction
        grids are compared against).
        """
        occ = np.zeros((grid.rows, grid.cols), dtype=bool)
        boxes = list(self.walls) + ([p for o in self.objects for p in o.parts] if objects else [])
        for box in boxes:
            if box.max[2] < self.floor_z + z_min or box.min[2] > self.floor_z + z_max:
                continue
            _paint_box(occ, grid, box)
        return occ

    def ambiguous(self, grid: GridSpec, z_min: float, z_max: float, *, tol_m: float = 1e-6) -> np.ndarray:
        """``(rows, cols)`` bool: cells whose centre lies on a footprint edge of a box :meth:`occupancy` paints.

        A face through a cell centre (a wall at x = 1.30 m and centres every 5 cm) makes the cell's
        "centre inside" label a matter of floating-point rounding, on either side; accuracy figures
        leave these cells out (:func:`pipeline.recon.evaluate.grid_accuracy`).
        """
        out = np.zeros((grid.rows, grid.cols), dtype=bool)
        centres = grid.cell_to_world(np.stack([np.zeros(grid.cols, int), np.arange(grid.cols)], axis=1))
        xs = centres[:, 0]
        ys = grid.cell_to_world(np.stack([np.arange(grid.rows), np.zeros(grid.rows, int)], axis=1))[:, 1]
        for box in list(self.walls) + [p for o in self.objects for p in o.parts]:
            if box.max[2] < self.floor_z + z_min or box.min[2] > self.floor_z + z_max:
                continue
            in_x = (xs >= box.min[0] - tol_m) & (xs <= box.max[0] + tol_m)
            in_y = (ys >= box.min[1] - tol_m) & (ys <= box.max[1] + tol_m)
            on_x = (np.abs(xs - box.min[0]) <= tol_m) | (np.abs(xs - box.max[0]) <= tol_m)
            on_y = (np.abs(ys - box.min[1]) <= tol_m) | (np.abs(ys - box.max[1]) <= tol_m)
            out |= (in_y[:, None] & on_x[None, :]) | (on_y[:, None] & in_x[None, :])
        return out

    def floor_mask(self, grid: GridSpec) -> np.ndarray:
        """``(rows, cols)`` bool: cells whose centre lies inside some room polygon."""
        import cv2

        mask = np.zeros((grid.rows, grid.cols), dtype=np.uint8)
        for room in self.rooms:
            rc = grid.world_to_cell(np.asarray(room.polygon)).astype(np.int32)
            cv2.fillPoly(mask, [rc[:, ::-1].reshape(-1, 1, 2)], 1)
        return mask.astype(bool)

    def instance_footprints(self, grid: GridSpec) -> np.ndarray:
        """``(rows, cols)`` uint16: the instance id covering each cell (0 = none; taller parts win)."""
        out = np.zeros((grid.rows, grid.cols), dtype=np.uint16)
        parts = sorted(((p.max[2], o.id, p) for o in self.objects for p in o.parts), key=lambda t: t[0])
        for _, oid, part in parts:
            m = np.zeros_like(out, dtype=bool)
            _paint_box(m, grid, part)
            out[m] = oid
        return out


def _paint_box(mask: np.ndarray, grid: GridSpec, box: Box) -> None:
    """Set cells whose centres fall inside the box's x/y footprint."""
    x0, x1, y0, y1 = grid.extent_xy
    s = grid.cell_size_m
    c_lo = int(np.ceil((box.min[0] - x0) / s - 0.5))
    c_hi = int(np.floor((box.max[0] - x0) / s - 0.5))
    r_lo = int(np.ceil((y1 - box.max[1]) / s - 0.5))
    r_hi = int(np.floor((y1 - box.min[1]) / s - 0.5))
    c_lo, r_lo = max(c_lo, 0), max(r_lo, 0)
    c_hi, r_hi = min(c_hi, grid.cols - 1), min(r_hi, grid.rows - 1)
    if c_lo <= c_hi and r_lo <= r_hi:
        mask[r_lo : r_hi + 1, c_lo : c_hi + 1] = True
