"""Scene generation: floor plan + furniture -> :class:`~pipeline.scene_gt.GTScene`, deterministic per seed."""

from __future__ import annotations

import hashlib

import numpy as np

from pipeline.config import SimulateParams
from pipeline.scene_gt import Box, GTRoom, GTScene
from pipeline.sim.furnish import furnish
from pipeline.sim.layout import FloorPlan, generate_floor_plan

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


def generate_scene(scene: str, params: SimulateParams) -> GTScene:
    """The procedural apartment of ``scene``: rooms, walls (doorways as gaps) and furniture."""
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
