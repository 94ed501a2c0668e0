"""Object records: the things goals are made of, in world coordinates.

Sources: the simulator's ground truth (:func:`objects_from_gt`), a user file
(:func:`objects_from_file`, YAML/JSON in the :class:`ObjectSet` layout), or navchat's
annotations (:mod:`pipeline.goals.navchat`). Every object carries a stable ``key``
(``<class>_<k>``, k counting instances of the class in instance-id order, as navchat names them),
its footprint polygon on the floor (world x/y metres, counter-clockwise), its mass centre, height
range, room and appearance attributes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import cv2
import numpy as np
import skimage.draw
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_serializer

from pipeline.errors import InputDataError, shown
from pipeline.geometry import GridSpec
from pipeline.scene_gt import GTScene
from pipeline.userfiles import load_user_file


def strict_number(value: object) -> object:
    """Numbers in user files are numbers: ``true`` and ``"3"`` are not (pydantic's lax mode takes both).
    Finite values are the models' business (``allow_inf_nan=False``)."""
    if isinstance(value, bool):
        raise ValueError(f"expected a number, got {str(value).lower()} (a boolean)")
    if isinstance(value, str):
        raise ValueError(f"expected a number, got the string {value!r}")
    return value


Number = Annotated[float, BeforeValidator(strict_number)]
Count = Annotated[int, BeforeValidator(strict_number)]
XY = tuple[Number, Number]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _OnAFloor(_Model):
    """A record that lies on one floor of a building (``floor``, 0 = the lowest). Floor 0 is not written out, so
    a single-floor scene's records (and the digests of what stores them) are as before floors existed."""

    floor: Count = Field(0, ge=0, description="id of the floor it lies on (a building's floors count up from 0)")

    @model_serializer(mode="wrap")
    def _floor_0_unwritten(self, handler) -> dict:
        data = handler(self)
        if data.get("floor") == 0:
            data.pop("floor")
        return data


class RoomRecord(_OnAFloor):
    id: str = Field(description="unique room id, e.g. 'bedroom_1'")
    type: str = Field(description="bedroom, living room, kitchen, bathroom, office, ...")
    polygon: list[XY] = Field(default_factory=list, description="floor outline, world x/y metres")


class ObjectRecord(_OnAFloor):
    key: str = Field(description="unique object key in the scene, e.g. 'chair_0'")
    cls: str = Field(description="object class, e.g. 'chair'")
    instance_id: Count = Field(ge=0, description="instance id in the instance images (0 = unknown)")
    room: str | None = Field(None, description="id of the room it stands in")
    footprint: list[XY] = Field(min_length=3, description="floor polygon, world x/y metres, CCW")
    mass_center: XY = Field(description="centroid of the footprint, world x/y metres")
    z_range: XY = Field((0.0, 1.0), description="bottom and top above its floor, metres")
    size: Literal["big", "small"] = Field("big", description="big (furniture) or small (on or beside furniture)")
    color_name: str = ""
    material: str = ""
    description: list[str] = Field(default_factory=list, description="human-written appearance/state text")

    @property
    def area_m2(self) -> float:
        return polygon_area(np.asarray(self.footprint))


class ObjectSet(_Model):
    """All objects (and rooms) of one scene; what the goals stage consumes."""

    scene: str
    source: Literal["gt", "file", "navchat"] = "file"
    rooms: list[RoomRecord] = Field(default_factory=list)
    objects: list[ObjectRecord]

    def by_key(self) -> dict[str, ObjectRecord]:
        return {o.key: o for o in self.objects}


# ----------------------------------------------------------------------------- polygons

def polygon_area(poly: np.ndarray) -> float:
    """Unsigned shoelace area of an ``(N,2)`` polygon."""
    x, y = poly[:, 0], poly[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


def polygon_centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of an ``(N,2)`` simple polygon (vertex mean when degenerate)."""
    x, y = poly[:, 0], poly[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    a = cross.sum() / 2.0
    if abs(a) < 1e-12:
        return poly.mean(axis=0)
    cx = ((x + np.roll(x, -1)) * cross).sum() / (6 * a)
    cy = ((y + np.roll(y, -1)) * cross).sum() / (6 * a)
    return np.array([cx, cy])


def rasterize_polygons(polys: list[np.ndarray], grid: GridSpec, values: list[int] | None = None) -> np.ndarray:
    """Paint world polygons on the grid: ``(rows, cols)`` int32, cell = value of the last polygon covering it.

    ``values`` default to ``1..N``; 0 means no polygon. A polygon smaller than a cell still marks
    the cell under its centroid, so every object is visible on the grid.
    """
    out = np.zeros((grid.rows, grid.cols), dtype=np.int32)
    values = values if values is not None else list(range(1, len(polys) + 1))
    for poly, v in zip(polys, values):
        poly = np.asarray(poly, dtype=np.float64)
        # polygon vertices in continuous (row, col) cell coordinates (cell centres at integers); a
        # cell belongs to the polygon when its centre lies inside (as GTScene rasterises boxes)
        x0, y1 = grid.origin_xy
        rows = (y1 - poly[:, 1]) / grid.cell_size_m - 0.5
        cols = (poly[:, 0] - x0) / grid.cell_size_m - 0.5
        rr, cc = skimage.draw.polygon(rows, cols, shape=out.shape)  # the cells of the polygon's box only
        out[rr, cc] = v
        rc = grid.world_to_cell(polygon_centroid(poly))
        if grid.inside(rc):
            out[rc[0], rc[1]] = v
    return out


def _ccw(poly: np.ndarray) -> np.ndarray:
    x, y = poly[:, 0], poly[:, 1]
    signed = np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))
    return poly if signed >= 0 else poly[::-1]


def _union_outline(boxes_xy: np.ndarray, step: float = 0.01) -> np.ndarray:
    """Outline of a union of axis-aligned rectangles ``(K,4)`` (x0, y0, x1, y1): the largest contour
    of their raster at ``step`` metres, simplified; the convex hull when the parts do not touch."""
    lo = boxes_xy[:, :2].min(axis=0)
    hi = boxes_xy[:, 2:].max(axis=0)
    if len(boxes_xy) == 1:
        x0, y0, x1, y1 = boxes_xy[0]
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    shape = np.ceil((hi - lo) / step).astype(int) + 3
    img = np.zeros((shape[1], shape[0]), np.uint8)
    for x0, y0, x1, y1 in boxes_xy:
        c0, r0 = np.floor((np.array([x0, y0]) - lo) / step).astype(int) + 1
        c1, r1 = np.ceil((np.array([x1, y1]) - lo) / step).astype(int) + 1
        img[r0:r1, c0:c1] = 1
    contours, _ = cv2.findContours(img, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if len(contours) != 1:
        corners = np.concatenate([boxes_xy[:, [0, 1]], boxes_xy[:, [2, 1]], boxes_xy[:, [2, 3]], boxes_xy[:, [0, 3]]])
        hull = cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        return hull
    pts = contours[0].reshape(-1, 2).astype(np.float64)
    return (pts - 1) * step + lo


# ----------------------------------------------------------------------------- sources

def objects_from_gt(gt: GTScene | dict, scene: str | None = None) -> ObjectSet:
    """Object records from a simulator ground truth (a :class:`GTScene` or its dict)."""
    gt = gt if isinstance(gt, GTScene) else GTScene.model_validate(gt)
    counts: dict[str, int] = {}
    records = []
    for obj in sorted(gt.objects, key=lambda o: o.id):
        k = counts.get(obj.cls, 0)
        counts[obj.cls] = k + 1
        boxes = np.array([[p.min[0], p.min[1], p.max[0], p.max[1]] for p in obj.parts])
        outline = _ccw(np.round(_union_outline(boxes), 4))
        floor_z = gt.all_floors[obj.floor].floor_z  # heights above the object's own floor
        zmin = min(p.min[2] for p in obj.parts) - floor_z
        zmax = max(p.max[2] for p in obj.parts) - floor_z
        records.append(ObjectRecord(
            key=f"{obj.cls}_{k}", cls=obj.cls, instance_id=obj.id, room=obj.room,
            footprint=[tuple(map(float, p)) for p in outline],
            mass_center=tuple(np.round(polygon_centroid(outline), 4).tolist()),
            z_range=(round(float(zmin), 4), round(float(zmax), 4)), size=obj.size,
            color_name=obj.color_name, material=obj.material, floor=obj.floor,
        ))
    rooms = [RoomRecord(id=r.id, type=r.type, polygon=list(r.polygon), floor=r.floor) for r in gt.rooms]
    return ObjectSet(scene=scene or gt.name, source="gt", rooms=rooms, objects=records)


def read_structured(path: Path) -> object:
    """A YAML (.yaml/.yml) or JSON file as plain data, within :mod:`pipeline.userfiles`' limits; errors name the file."""
    return load_user_file(path)


def validation_error(err: ValidationError, path: Path | str | None, prefix: str = "") -> InputDataError:
    """The first pydantic error as an :class:`InputDataError` naming the field path and the reason."""
    def where(e: dict) -> str:
        return prefix + "".join(f"[{p}]" if isinstance(p, int) else f".{shown(p)}" for p in e["loc"]).lstrip(".")

    lines = []
    for e in err.errors():
        msg = e["msg"].removeprefix("Value error, ")  # a model check's message names its own field path
        lines.append(f"{where(e)}: {msg}" if where(e) else msg)
    return InputDataError("; ".join(lines), path=path, field=where(err.errors()[0]) or None)


def objects_from_file(path: Path, scene: str) -> ObjectSet:
    """A user file (YAML/JSON) with ``rooms`` and ``objects`` in the :class:`ObjectSet` layout."""
    return objects_from_data(read_structured(path), scene, path)


def objects_from_data(raw: object, scene: str, path: Path | str | None = None) -> ObjectSet:
    """:func:`objects_from_file`'s checks on data already read (``path`` names its origin in errors)."""
    if not isinstance(raw, dict):
        raise InputDataError("expected a mapping with 'objects' (and optional 'rooms')", path=path)
    raw = {"scene": scene, "source": "file", **raw}
    try:
        objs = ObjectSet.model_validate(raw)
    except ValidationError as err:
        raise validation_error(err, path) from None
    keys = [o.key for o in objs.objects]
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise InputDataError(f"duplicate object keys {dup}", path=path, field="objects", expected="unique keys")
    room_ids = {r.id for r in objs.rooms}
    for i, o in enumerate(objs.objects):
        if objs.rooms and o.room is not None and o.room not in room_ids:
            raise InputDataError(f"room {o.room!r} is not one of {sorted(room_ids)}", path=path,
                                 field=f"objects[{i}].room")
    return objs
