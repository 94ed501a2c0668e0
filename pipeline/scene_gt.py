"""Ground truth of a simulated (or annotated) scene: rooms, walls and objects; floors and stairs of a building.

Stored as JSON in the raw MCAP log (attachment ``ground_truth.json``) and carried by ingest into
``frames.zarr`` attrs (``ground_truth``). Every solid is a world-axis-aligned box in metres,
z up, floor at ``floor_z``; an object is the union of its part boxes.

A building of several floors lists them (``floors``: id, name, floor and ceiling height) and the
stairs that join them (``stairs``: footprint, opening in the upper floor, steps); each room and
object names its floor. A single-floor scene leaves ``floors`` empty (one implied floor,
:attr:`GTScene.all_floors`) and its document is written exactly as before floors existed.
:meth:`GTScene.floor_view` is one floor as a single-floor scene, so every top-down measure of
a single floor (:meth:`~GTScene.occupancy`, :meth:`~GTScene.floor_mask`) applies per floor.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_serializer, model_validator

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
    polygon: list[tuple[float, float]] = Field(description="floor outline, world x/y metres, counter-clockwise "
                                               "(a stair opening in the floor is cut out of it)")
    floor: int = Field(0, ge=0, description="id of the floor it lies on")


class GTObject(_Model):
    id: int = Field(ge=1, description="instance id as written in the instance images (0 = none)")
    cls: str = Field(description="object class, e.g. 'chair'")
    room: str = Field(description="id of the room it stands in")
    parts: list[Box] = Field(min_length=1, description="solid parts; the object is their union")
    color_name: str = Field(description="dominant colour in words, e.g. 'dark green'")
    color_rgb: tuple[int, int, int]
    material: str = Field(description="e.g. 'wood', 'leather', 'metal', 'fabric'")
    size: Literal["big", "small"] = Field(description="big (furniture) or small (on or beside furniture)")
    floor: int = Field(0, ge=0, description="id of the floor it stands on")

    @property
    def bbox(self) -> Box:
        mins = np.min([p.min for p in self.parts], axis=0)
        maxs = np.max([p.max for p in self.parts], axis=0)
        return Box(min=tuple(mins.tolist()), max=tuple(maxs.tolist()))

    @property
    def center(self) -> np.ndarray:
        return self.bbox.center


class GTFloor(_Model):
    """One floor (storey) of a building: its walking surface and its ceiling."""

    id: int = Field(ge=0, description="0 = the lowest floor, counting up")
    name: str = Field(description="e.g. 'ground floor', 'first floor'")
    floor_z: float = Field(description="height of the walking surface, world z metres")
    ceiling_z: float = Field(description="height of the ceiling above it, world z metres")


class GTStair(_Model):
    """A straight flight of stairs from floor ``lower`` up to floor ``upper``.

    ``footprint`` is what the flight covers on the lower floor; ``opening`` the hole it needs in the
    upper floor (cut out of that floor's rooms); ``bottom`` / ``top`` the world points (x, y, z on
    the walking surface) at the foot of the first riser and at the edge of the upper floor, centred
    across the flight; ``steps`` its solids (step k from the lower floor up to its tread).
    """

    id: str = Field(description="e.g. 'stairs_0_1'")
    lower: int = Field(ge=0, description="id of the floor at its foot")
    upper: int = Field(ge=1, description="id of the floor at its top")
    footprint: list[tuple[float, float]] = Field(description="outline on the lower floor, world x/y, counter-clockwise")
    opening: list[tuple[float, float]] = Field(description="hole in the upper floor, world x/y, counter-clockwise")
    bottom: tuple[float, float, float] = Field(description="foot of the first riser, centre of the flight, world m")
    top: tuple[float, float, float] = Field(description="top edge on the upper floor, centre of the flight, world m")
    steps: list[Box] = Field(min_length=1, description="solid steps, lowest first")

    def surface_z(self, xy: np.ndarray) -> np.ndarray:
        """Height ``(...)`` of the walking surface over the flight at world ``xy (..., 2)``: the straight ramp from
        :attr:`bottom` to :attr:`top` (the slope a navigation mesh lays over the step nosings), clamped at both ends."""
        b, t = np.asarray(self.bottom), np.asarray(self.top)
        run = t[:2] - b[:2]
        frac = np.clip((np.asarray(xy, float) - b[:2]) @ run / float(run @ run), 0.0, 1.0)
        return b[2] + frac * (t[2] - b[2])


class GTScene(_Model):
    format_version: int = GT_FORMAT_VERSION
    name: str
    seed: int
    floor_z: float = Field(0.0, description="height of the (lowest) floor, world z metres")
    wall_height_m: float = Field(description="floor to ceiling of the (lowest) floor, metres")
    rooms: list[GTRoom]
    walls: list[Box] = Field(description="wall segments (doorways are gaps between them) and railings, every floor")
    objects: list[GTObject]
    floors: list[GTFloor] = Field(default_factory=list, description="the floors of a building, lowest first; empty: "
                                  "one floor at floor_z (a single-floor scene)")
    stairs: list[GTStair] = Field(default_factory=list, description="flights joining consecutive floors")

    @model_validator(mode="after")
    def _floors_consistent(self) -> "GTScene":
        ids = [f.id for f in self.floors]
        if ids and ids != list(range(len(ids))):
            raise ValueError(f"floors: ids must be 0, 1, ... in order, got {ids}")
        for lo, hi in zip(self.floors[:-1], self.floors[1:]):
            if not (lo.floor_z < lo.ceiling_z <= hi.floor_z):
                raise ValueError(f"floors: floor {hi.id} must lie above floor {lo.id}'s ceiling")
        if self.floors and (self.floors[0].floor_z != self.floor_z
                            or abs(self.floors[0].ceiling_z - self.floor_z - self.wall_height_m) > 1e-6):
            raise ValueError("floor_z / wall_height_m must be floor 0's floor_z and ceiling_z - floor_z")
        n = max(len(self.floors), 1)
        for kind, items in (("rooms", self.rooms), ("objects", self.objects)):
            bad = [item.id for item in items if item.floor >= n]
            if bad:
                raise ValueError(f"{kind} {bad[:5]}: floor is not one of the {n} floors")
        for stair in self.stairs:
            if stair.upper != stair.lower + 1 or stair.upper >= len(self.floors):
                raise ValueError(f"stairs {stair.id}: must join a floor to the one above it (lower {stair.lower}, "
                                 f"upper {stair.upper}, {len(self.floors)} floors)")
        return self

    @model_serializer(mode="wrap")
    def _single_floor_as_before(self, handler) -> dict:
        # a single-floor document keeps the exact layout written before floors existed (same bytes, same digests)
        data = handler(self)
        if not self.floors:
            data.pop("floors", None)
            data.pop("stairs", None)
            for item in (*data.get("rooms", ()), *data.get("objects", ())):
                item.pop("floor", None)
        return data

    @property
    def all_floors(self) -> list[GTFloor]:
        """The floors, lowest first: :attr:`floors`, or the one floor of a single-floor scene."""
        if self.floors:
            return list(self.floors)
        return [GTFloor(id=0, name="ground floor", floor_z=self.floor_z, ceiling_z=self.floor_z + self.wall_height_m)]

    def floor_view(self, floor: int) -> "GTScene":
        """Floor ``floor`` as a single-floor scene: its rooms and objects, the walls and railings standing on it,
        the steps of the stairs rising from it (solids in its height band). Every single-floor measure
        (:meth:`occupancy`, :meth:`floor_mask`, :meth:`instance_footprints`) then applies to that floor."""
        floors = self.all_floors
        if not 0 <= floor < len(floors):
            raise KeyError(f"scene {self.name}: no floor {floor} (floors 0..{len(floors) - 1})")
        if not self.floors:
            return self
        f = floors[floor]

        def on_floor(box: Box) -> bool:
            return box.min[2] < f.ceiling_z - 1e-6 and box.max[2] > f.floor_z + 1e-6

        solids = [w for w in self.walls if on_floor(w)]
        solids += [s for st in self.stairs if st.lower == floor for s in st.steps if on_floor(s)]
        return GTScene(name=f"{self.name}/{f.name}", seed=self.seed, floor_z=f.floor_z,
                       wall_height_m=round(f.ceiling_z - f.floor_z, 6),
                       rooms=[r.model_copy(update={"floor": 0}) for r in self.rooms if r.floor == floor],
                       walls=solids,
                       objects=[o.model_copy(update={"floor": 0}) for o in self.objects if o.floor == floor])

    def floor_at(self, z: float) -> int:
        """The id of the floor whose band ``[floor_z, next floor_z)`` holds height ``z`` (the lowest below it)."""
        floors = self.all_floors
        k = 0
        for f in floors:
            if z >= f.floor_z - 1e-6:
                k = f.id
        return k

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
