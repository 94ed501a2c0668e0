"""Furnishing rooms: per-room-type recipes placed by rejection sampling.

Big objects stand on the floor against a wall, in the middle of the room, around a table or in
front of a desk; small ones stand on a supporting object's top. A floor object is accepted only
if it keeps a 1 m deep zone in front of every doorway empty and every doorway of the room still
connects to the room's free space for a robot of ``robot_radius_m`` (plus a margin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pipeline.scene_gt import Box, GTObject
from pipeline.sim.catalog import COLOURS, TEMPLATES, front_quarter_turns, place_parts
from pipeline.sim.layout import WALL_THICKNESS_M, FloorPlan, Rect

# (template key, min count, max count, mode, mode argument)
#   wall: back against a wall; center: free in the room; on: on top of one of the given keys;
#   around: chairs facing a placed table; front: facing a placed desk; high: hung on a wall.
RECIPES: dict[str, list[tuple]] = {
    "bedroom": [("bed", 1, 1, "wall", None), ("wardrobe", 1, 1, "wall", None), ("nightstand", 1, 2, "wall", None),
                ("table lamp", 1, 1, "on", ("nightstand",)), ("plant", 0, 1, "wall", None),
                ("chair", 0, 1, "wall", None), ("picture", 1, 2, "high", None),
                ("small plant", 0, 1, "on", ("nightstand",))],
    "living room": [("couch", 1, 1, "wall", None), ("coffee table", 1, 1, "front", ("couch",)),
                    ("cabinet", 1, 1, "wall", None), ("tv", 1, 1, "on", ("cabinet",)),
                    ("armchair", 1, 2, "wall", None), ("shelf", 1, 1, "wall", None), ("plant", 1, 2, "wall", None),
                    ("lamp", 1, 1, "wall", None), ("picture", 1, 2, "high", None),
                    ("small plant", 0, 1, "on", ("coffee table",))],
    "kitchen": [("fridge", 1, 1, "wall", None), ("stove", 1, 1, "wall", None), ("sink", 1, 1, "wall", None),
                ("counter", 1, 2, "wall", None), ("microwave", 1, 1, "on", ("counter",)),
                ("table", 1, 1, "center", None), ("chair", 2, 4, "around", ("table",)),
                ("small plant", 0, 1, "on", ("table",)), ("picture", 0, 1, "high", None)],
    "bathroom": [("toilet", 1, 1, "wall", None), ("sink", 1, 1, "wall", None), ("bathtub", 0, 1, "wall", None),
                 ("cabinet", 0, 1, "wall", None), ("small plant", 0, 1, "on", ("cabinet",)),
                 ("picture", 0, 1, "high", None)],
    "office": [("desk", 1, 1, "wall", None), ("chair", 1, 1, "front", ("desk",)), ("computer", 1, 1, "on", ("desk",)),
               ("table lamp", 0, 1, "on", ("desk",)), ("shelf", 1, 2, "wall", None), ("plant", 1, 1, "wall", None),
               ("cabinet", 0, 1, "wall", None), ("lamp", 0, 1, "wall", None), ("picture", 0, 1, "high", None)],
    # buildings (pipeline.sim.building): a house's stair hall, an office floor's shared rooms
    "hallway": [("plant", 0, 1, "wall", None), ("cabinet", 0, 1, "wall", None), ("picture", 1, 2, "high", None)],
    "open office": [("desk", 2, 5, "center", None), ("desk", 1, 2, "wall", None), ("chair", 3, 6, "front", ("desk",)),
                    ("computer", 2, 4, "on", ("desk",)), ("shelf", 1, 1, "wall", None), ("cabinet", 1, 2, "wall", None),
                    ("plant", 1, 2, "wall", None), ("picture", 0, 1, "high", None)],
    "meeting room": [("table", 1, 1, "center", None), ("chair", 3, 4, "around", ("table",)),
                     ("cabinet", 0, 1, "wall", None), ("tv", 1, 1, "on", ("cabinet",)), ("plant", 0, 1, "wall", None),
                     ("picture", 1, 1, "high", None)],
}
# Classes every apartment holds at least this many instances of (each a different colour, so each its own
# goal): personalized goals are only hard when several instances share a class, as in the paper's HM3D
# scenes (3-6 chairs, several cabinets and pictures). After the recipes, :func:`furnish` tops a short
# class up with the recipe entries of that class (in the rooms whose recipe has one), rooms in seeded order.
MIN_INSTANCES: dict[str, int] = {"chair": 3, "cabinet": 3, "picture": 3}
TOP_UP_ROUNDS = 4  # passes over the candidate rooms before a class is left short (a very small apartment)
SIDES = ((0, 1), (0, -1), (1, 0), (-1, 0))  # inward normals of the south, north, west, east walls
CELL_M = 0.05
DOOR_ZONE_DEPTH_M = 1.0


@dataclass
class Placed:
    key: str
    cls: str
    parts: list[tuple[np.ndarray, np.ndarray]]
    footprint: tuple[float, float, float, float]  # x0, y0, x1, y1
    quarter_turns: int
    on_floor: bool


class RoomFurnisher:
    """Places one room's objects; ``placed`` holds the accepted ones."""

    def __init__(self, rng: np.random.Generator, plan: FloorPlan, room: int, robot_radius_m: float,
                 keep_out: tuple[Rect, ...] = (), blocked: tuple[Rect, ...] = (),
                 entries: tuple[tuple[float, float], ...] = ()):
        """``keep_out``: more rectangles to leave empty (a stair landing); ``blocked``: rectangles that are not floor
        (a flight, an opening), left empty and no way through; ``entries``: more spots (where a flight is taken)
        that must stay joined to the doorways."""
        r = plan.rooms[room]
        t = WALL_THICKNESS_M / 2
        self.rng = rng
        self.inner = Rect(r.x0 + t, r.y0 + t, r.x1 - t, r.y1 - t)
        self.radius = robot_radius_m + 0.04
        self.placed: list[Placed] = []
        self.door_zones = []
        self.entries = []
        for d in plan.doors:
            if room not in d.rooms:
                continue
            sign = 1.0 if (d.axis == 0 and abs(d.at - r.x0) < 1e-6) or (d.axis == 1 and abs(d.at - r.y0) < 1e-6) else -1.0
            a, b = d.at + sign * t, d.at + sign * (t + DOOR_ZONE_DEPTH_M)
            lo, hi = d.lo - 0.15, d.hi + 0.15
            zone = (min(a, b), lo, max(a, b), hi) if d.axis == 0 else (lo, min(a, b), hi, max(a, b))
            self.door_zones.append(zone)
            c = (d.lo + d.hi) / 2
            inside = d.at + sign * (t + 0.3)
            self.entries.append((inside, c) if d.axis == 0 else (c, inside))
        self.blocked = [(z.x0, z.y0, z.x1, z.y1) for z in blocked]
        self.door_zones += [(z.x0, z.y0, z.x1, z.y1) for z in keep_out] + self.blocked
        self.entries += [tuple(e) for e in entries]
        self.shape = (int(np.ceil(self.inner.h / CELL_M)), int(np.ceil(self.inner.w / CELL_M)))

    # -- checks
    def _fits(self, fp, margin=0.05) -> bool:
        x0, y0, x1, y1 = fp
        i = self.inner
        if x0 < i.x0 - 1e-6 or y0 < i.y0 - 1e-6 or x1 > i.x1 + 1e-6 or y1 > i.y1 + 1e-6:
            return False
        others = [p.footprint for p in self.placed if p.on_floor] + self.door_zones
        return not any(x0 < o[2] + margin and o[0] - margin < x1 and y0 < o[3] + margin and o[1] - margin < y1
                       for o in others)

    def _reachable(self, fp) -> bool:
        """Every doorway entry still lies in one free component with room to turn in place."""
        occ = np.zeros(self.shape, dtype=bool)
        for x0, y0, x1, y1 in [p.footprint for p in self.placed if p.on_floor] + [fp] + self.blocked:
            c0, c1 = int((x0 - self.inner.x0) / CELL_M), int(np.ceil((x1 - self.inner.x0) / CELL_M))
            r0, r1 = int((y0 - self.inner.y0) / CELL_M), int(np.ceil((y1 - self.inner.y0) / CELL_M))
            occ[max(r0, 0):r1, max(c0, 0):c1] = True
        padded = np.pad(~occ, 1, constant_values=False)
        clearance = ndimage.distance_transform_edt(padded)[1:-1, 1:-1] * CELL_M
        free = clearance > self.radius
        labels, _ = ndimage.label(free)
        cells = [(int((y - self.inner.y0) / CELL_M), int((x - self.inner.x0) / CELL_M)) for x, y in self.entries]
        if not cells:  # a room with no doorway cannot happen in a plan, but keep a turning spot
            return bool(free.any())
        ids = {int(labels[min(r, self.shape[0] - 1), min(c, self.shape[1] - 1)]) for r, c in cells}
        if 0 in ids or len(ids) != 1:
            return False
        return bool((labels == ids.pop()).sum() * CELL_M**2 >= 1.0)

    # -- placement
    def _accept(self, key, parts_local, xy, z0, qt, on_floor) -> Placed | None:
        boxes = place_parts(parts_local, xy, z0, qt)
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        fp = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
        if on_floor and not (self._fits(fp) and self._reachable(fp)):
            return None
        placed = Placed(key, TEMPLATES[key].cls, boxes, fp, qt, on_floor)
        self.placed.append(placed)
        return placed

    def _wall_xy(self, side, w, d, gap=0.02):
        """Centre of a ``w x d`` footprint backed against wall ``side`` at a random position along it."""
        i = self.inner
        nx, ny = side
        if nx == 0:
            lo, hi = i.x0 + w / 2, i.x1 - w / 2
            y = (i.y0 + gap + d / 2) if ny > 0 else (i.y1 - gap - d / 2)
            return (float(self.rng.uniform(lo, hi)), y) if hi > lo else None
        lo, hi = i.y0 + w / 2, i.y1 - w / 2
        x = (i.x0 + gap + d / 2) if nx > 0 else (i.x1 - gap - d / 2)
        return (x, float(self.rng.uniform(lo, hi))) if hi > lo else None

    def place(self, key: str, mode: str, arg, tries: int = 40) -> Placed | None:
        tpl = TEMPLATES[key]
        w, d, parts = tpl.build(self.rng)
        for _ in range(tries):
            if mode in ("wall", "high"):
                side = SIDES[int(self.rng.integers(4))]
                xy = self._wall_xy(side, w, d, gap=0.0 if mode == "high" else 0.02)
                if xy is None:
                    continue
                qt = front_quarter_turns(side)
                if mode == "high":
                    got = self._hang(key, parts, xy, qt)
                else:
                    got = self._accept(key, parts, xy, 0.0, qt, True)
            elif mode == "center":
                i = self.inner
                m = max(w, d) / 2 + 0.5
                if i.x1 - i.x0 <= 2 * m or i.y1 - i.y0 <= 2 * m:
                    return self.place(key, "wall", None, tries)  # small room: against a wall
                xy = (float(self.rng.uniform(i.x0 + m, i.x1 - m)), float(self.rng.uniform(i.y0 + m, i.y1 - m)))
                got = self._accept(key, parts, xy, 0.0, int(self.rng.integers(4)), True)
            elif mode in ("front", "around"):
                return self._facing(key, parts, d, arg, mode)  # deterministic spots: one try
            elif mode == "on":
                got = self._on_top(key, parts, w, d, arg)
            else:
                raise ValueError(f"unknown placement mode {mode!r}")
            if got is not None:
                return got
        return None

    def _hang(self, key, parts, xy, qt) -> Placed | None:
        z0 = float(self.rng.uniform(1.2, 1.5))
        boxes = place_parts(parts, xy, z0, qt)
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        for zone in self.door_zones:  # never above a doorway
            if lo[0] < zone[2] + 0.1 and zone[0] - 0.1 < hi[0] and lo[1] < zone[3] + 0.1 and zone[1] - 0.1 < hi[1]:
                return None
        for p in self.placed:
            for b0, b1 in p.parts:
                if np.all(lo < b1 + 0.05) and np.all(b0 - 0.05 < hi):
                    return None
        placed = Placed(key, TEMPLATES[key].cls, boxes, (lo[0], lo[1], hi[0], hi[1]), qt, False)
        self.placed.append(placed)
        return placed

    def _facing(self, key, parts, d, targets, mode) -> Placed | None:
        hosts = [p for p in self.placed if p.key in targets]
        if not hosts:
            return None
        host = hosts[int(self.rng.integers(len(hosts)))]
        x0, y0, x1, y1 = host.footprint
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        if mode == "front":  # in front of the host's front face
            sides = [[(0, 1), (-1, 0), (0, -1), (1, 0)][host.quarter_turns]]
            gap = 0.45 if key == "coffee table" else 0.08
        else:
            sides = [SIDES[i] for i in self.rng.permutation(4)]
            gap = 0.1
        for nx, ny in sides:
            half = (x1 - x0) / 2 if nx else (y1 - y0) / 2
            xy = (cx + nx * (half + gap + d / 2), cy + ny * (half + gap + d / 2))
            got = self._accept(key, parts, xy, 0.0, front_quarter_turns((-nx, -ny)) if key != "coffee table"
                               else host.quarter_turns, True)
            if got is not None:
                return got
        return None

    def _on_top(self, key, parts, w, d, supports) -> Placed | None:
        hosts = [p for p in self.placed if p.key in supports]
        if not hosts:
            return None
        host = hosts[int(self.rng.integers(len(hosts)))]
        top = max(host.parts, key=lambda b: (b[1][2], (b[1][0] - b[0][0]) * (b[1][1] - b[0][1])))
        qt = host.quarter_turns
        ww, dd = (w, d) if qt % 2 == 0 else (d, w)
        lo_x, hi_x = top[0][0] + ww / 2 + 0.02, top[1][0] - ww / 2 - 0.02
        lo_y, hi_y = top[0][1] + dd / 2 + 0.02, top[1][1] - dd / 2 - 0.02
        if hi_x < lo_x or hi_y < lo_y:
            return None
        xy = (float(self.rng.uniform(lo_x, hi_x)), float(self.rng.uniform(lo_y, hi_y)))
        boxes = place_parts(parts, xy, float(top[1][2]), qt)
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        for p in self.placed:
            if not p.on_floor and p.footprint[0] < hi[0] and lo[0] < p.footprint[2] and p.footprint[1] < hi[1] \
                    and lo[1] < p.footprint[3]:
                return None
        placed = Placed(key, TEMPLATES[key].cls, boxes, (lo[0], lo[1], hi[0], hi[1]), qt, False)
        self.placed.append(placed)
        return placed


def _top_up(rng: np.random.Generator, plan: FloorPlan, furnishers: dict[int, RoomFurnisher]) -> None:
    """Place extra instances of each :data:`MIN_INSTANCES` class that is short, with its rooms' recipe entries."""
    for cls, wanted in MIN_INSTANCES.items():
        have = sum(p.cls == cls for f in furnishers.values() for p in f.placed)
        entries = [(room, key, mode, arg) for room in furnishers for key, _, _, mode, arg in RECIPES[plan.types[room]]
                   if TEMPLATES[key].cls == cls]
        for _ in range(TOP_UP_ROUNDS):
            if have >= wanted or not entries:
                break
            for i in rng.permutation(len(entries)):
                room, key, mode, arg = entries[int(i)]
                if furnishers[room].place(key, mode, arg) is not None:
                    have += 1
                    if have >= wanted:
                        break


def furnish(rng: np.random.Generator, plan: FloorPlan, robot_radius_m: float, *,
            keep_out: dict[int, tuple[Rect, ...]] | None = None, blocked: dict[int, tuple[Rect, ...]] | None = None,
            entries: dict[int, tuple[tuple[float, float], ...]] | None = None) -> list[GTObject]:
    """Objects for every room of ``plan``: its recipe, then the :data:`MIN_INSTANCES` top-up; ids 1.. in room
    order; distinct colours within a class. ``keep_out`` / ``blocked`` / ``entries`` per room index: see
    :class:`RoomFurnisher`."""
    used_colours: dict[str, set[str]] = {}
    objects: list[GTObject] = []
    order = sorted(range(len(plan.rooms)), key=lambda i: plan.ids[i])
    furnishers = {}
    for room in order:
        fur = furnishers[room] = RoomFurnisher(rng, plan, room, robot_radius_m, (keep_out or {}).get(room, ()),
                                               (blocked or {}).get(room, ()), (entries or {}).get(room, ()))
        for key, n_min, n_max, mode, arg in RECIPES[plan.types[room]]:
            for _ in range(int(rng.integers(n_min, n_max + 1))):
                fur.place(key, mode, arg)
    _top_up(rng, plan, furnishers)
    for room in order:
        for p in furnishers[room].placed:
            tpl = TEMPLATES[p.key]
            used = used_colours.setdefault(p.cls, set())
            choices = [c for c in tpl.colours if c not in used] or [c for c in COLOURS if c not in used] \
                or list(tpl.colours)
            colour = choices[int(rng.integers(len(choices)))]
            used.add(colour)
            objects.append(GTObject(
                id=len(objects) + 1, cls=p.cls, room=plan.ids[room],
                parts=[Box(min=tuple(float(v) for v in b0), max=tuple(float(v) for v in b1)) for b0, b1 in p.parts],
                color_name=colour, color_rgb=COLOURS[colour],
                material=tpl.materials[int(rng.integers(len(tpl.materials)))], size=tpl.size,
            ))
    return objects
