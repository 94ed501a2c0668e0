"""Scene generation: floor plan + furniture -> :class:`~pipeline.scene_gt.GTScene`, deterministic per seed.

An apartment (the default) is one floor plan; a house or an office (``building``, a scene's
:class:`~pipeline.config.BuildingParams`) is a :class:`~pipeline.sim.building.Building`."""

from __future__ import annotations

import hashlib

import numpy as np

from pipeline.config import BuildingParams, SimulateParams
from pipeline.scene_gt import Box, GTFloor, GTRoom, GTScene, GTStair
from pipeline.sim.building import FLOOR_NAMES, Building, generate_house, generate_office, notched_polygon
from pipeline.sim.furnish import furnish
from pipeline.sim.layout import FloorPlan, Rect, generate_floor_plan

# Independent random streams of one scene (numpy SeedSequence spawn keys).
STREAM_LAYOUT, STREAM_FURNISH, STREAM_DEPTH_NOISE, STREAM_POSE_NOISE = 1, 2, 3, 4


def scene_seed(base_seed: int, scene: str) -> int:
    """The scene's own seed: a stable digest of the base seed and the scene name (not ``hash()``)."""
    digest = hashlib.blake2b(f"zipon-sim:{int(base_seed)}:{scene}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") >> 1  # fits in int64


def scene_rng(seed: int, stream: int, *extra: int) -> np.random.Generator:
    """A generator for one stream (and e.g. one frame index) of a scene seed."""
    return np.random.default_rng(np.random.SeedSequence([seed, stream, *extra]))


def generate_floor(scene: str, params: SimulateParams) -> tuple[int, FloorPlan]:
    seed = scene_seed(params.seed, scene)
    rng = scene_rng(seed, STREAM_LAYOUT)
    n_rooms = int(rng.integers(params.rooms_min, params.rooms_max + 1))
    return seed, generate_floor_plan(rng, n_rooms)


def generate_scene(scene: str, params: SimulateParams, building: BuildingParams | None = None) -> GTScene:
    """The procedural scene of ``scene``: rooms, walls (doorways as gaps) and furniture; an apartment unless
    ``building`` says a house or an office."""
    if building is not None and building.kind != "apartment":
        return generate_building(scene, params, building)
    seed, plan = generate_floor(scene, params)
    objects = furnish(scene_rng(seed, STREAM_FURNISH), plan, params.robot_radius_m)
    rooms = []
    for rect, rid, rtype in sorted(zip(plan.rooms, plan.ids, plan.types), key=lambda t: t[1]):
        poly = [(rect.x0, rect.y0), (rect.x1, rect.y0), (rect.x1, rect.y1), (rect.x0, rect.y1)]
        rooms.append(GTRoom(id=rid, type=rtype, polygon=[(float(x), float(y)) for x, y in poly]))
    walls = [Box(min=tuple(round(float(v), 4) for v in lo), max=tuple(round(float(v), 4) for v in hi))
             for lo, hi in plan.walls]
    return GTScene(name=scene, seed=seed, wall_height_m=plan.wall_height_m, rooms=rooms, walls=walls,
                   objects=objects)


def _rect_polygon(r: Rect) -> list[tuple[float, float]]:
    return [(float(r.x0), float(r.y0)), (float(r.x1), float(r.y0)), (float(r.x1), float(r.y1)), (float(r.x0), float(r.y1))]


def _box(lo, hi) -> Box:
    return Box(min=tuple(round(float(v), 4) for v in lo), max=tuple(round(float(v), 4) for v in hi))


def generate_building(scene: str, params: SimulateParams, spec: BuildingParams) -> GTScene:
    """A house of ``spec.stories`` floors with its stairs, or an office floor of ``spec.size_m``, furnished."""
    seed = scene_seed(params.seed, scene)
    rng = scene_rng(seed, STREAM_LAYOUT)
    if spec.kind == "house":
        b: Building = generate_house(rng, spec.stories, (spec.rooms_per_floor_min, spec.rooms_per_floor_max))
    else:
        b = generate_office(rng, spec.size_m, spec.room_area_m2)
    furnish_rng = scene_rng(seed, STREAM_FURNISH)
    multi = len(b.plans) > 1
    rooms, walls, objects = [], [], []
    for floor, plan in enumerate(b.plans):
        z0 = b.floor_z[floor]
        hall = {b.hall: tuple(b.landings(floor))} if b.hall >= 0 else {}
        placed = furnish(furnish_rng, plan, params.robot_radius_m, keep_out=hall,
                         blocked={b.hall: tuple(b.blocked(floor))} if b.hall >= 0 else {},
                         entries={b.hall: tuple(b.stair_spots(floor))} if b.hall >= 0 else {})
        for obj in placed:
            parts = [_box((p.min[0], p.min[1], p.min[2] + z0), (p.max[0], p.max[1], p.max[2] + z0)) for p in obj.parts]
            objects.append(obj.model_copy(update={"id": len(objects) + 1, "parts": parts, "floor": floor}))
        holes = b.openings(floor)
        for k in sorted(range(len(plan.rooms)), key=lambda i: plan.ids[i]):
            r = plan.rooms[k]
            cut = [h for h in holes if k == b.hall]
            poly = notched_polygon(r, cut[0]) if cut else _rect_polygon(r)
            rooms.append(GTRoom(id=plan.ids[k], type=plan.types[k], polygon=poly, floor=floor))
        walls += [_box(lo + (0, 0, z0), hi + (0, 0, z0)) for lo, hi in plan.walls]
        walls += [_box(lo, hi) for lo, hi in b.railings(floor)]
    floors = [GTFloor(id=k, name=FLOOR_NAMES[k], floor_z=b.floor_z[k], ceiling_z=b.ceiling_z(k))
              for k in range(len(b.plans))] if multi else []
    stairs = []
    for f in b.flights:
        upper = f.lower + 1
        stairs.append(GTStair(id=f"stairs_{f.lower}_{upper}", lower=f.lower, upper=upper,
                              footprint=_rect_polygon(f.rect()), opening=_rect_polygon(b.openings(upper)[0]),
                              bottom=f.point(f.foot, b.floor_z[f.lower]), top=f.point(f.end, b.floor_z[upper]),
                              steps=[_box(lo, hi) for lo, hi in f.steps(b.floor_z[f.lower])]))
    return GTScene(name=scene, seed=seed, floor_z=b.floor_z[0], wall_height_m=b.wall_height_m, rooms=rooms,
                   walls=walls, objects=objects, floors=floors, stairs=stairs)
