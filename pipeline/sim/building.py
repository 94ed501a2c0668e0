"""Buildings beyond an apartment: a house of two or three floors joined by stairs, and a large office floor.

A house is one rectangular outline repeated on every floor. Along one long side runs a stair hall of
two 1 m lanes; the flight from floor 0 climbs lane A (against the outer wall) toward +a (the long
axis), the flight from floor 1 (a third floor) climbs lane B back toward -a, so the two share the
landing between them (a switchback). Each flight needs an opening in the floor above it, with a
railing along its open sides except the end one steps off at. The rest of each floor is split into
rooms as an apartment is (:mod:`pipeline.sim.layout`); the hall's one doorway lies on the landing
where that floor meets the stairs, so every room of every floor is reachable.

An office is one floor of ``size_m`` split into rooms of about ``room_area_m2`` (open offices, meeting
rooms, offices, kitchens, bathrooms) with extra doorways between neighbours, as corridors give.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.sim.layout import WALL_THICKNESS_M, FloorPlan, Rect, assign_types, split_plan

SLAB_M = 0.2  # floor slab between a ceiling and the floor above it
LANE_M = 1.0  # clear width of a stair lane (a flight is as wide)
HALL_M = 2 * LANE_M + WALL_THICKNESS_M  # wall centre line to wall centre line across the hall
TREAD_M = 0.28
MAX_RISE_M = 0.19  # a Habitat agent climbs up to 0.2 m per step
LANDING_M = 2.0  # free floor at each end of a flight, at least
RAILING_M = (1.0, 0.05)  # height, thickness
OFFICE_TYPES = ("open office", "meeting room", "office", "kitchen", "bathroom")
FLOOR_NAMES = ("ground floor", "first floor", "second floor")


@dataclass
class Flight:
    """A straight flight in plan coordinates: it climbs along ``axis`` (0 = x, 1 = y) in ``direction`` (+1/-1)
    from ``foot`` (the first riser) between ``lane`` (the across-axis range, world metres)."""

    lower: int
    axis: int
    direction: int
    foot: float
    lane: tuple[float, float]
    n_risers: int
    rise: float

    @property
    def end(self) -> float:
        """Along-axis coordinate of the last riser (the edge of the floor above)."""
        return self.foot + self.direction * (self.n_risers - 1) * TREAD_M

    def rect(self, across: tuple[float, float] | None = None, along: tuple[float, float] | None = None) -> Rect:
        """World rectangle of an along-axis range (default: the flight) and an across range (default: the lane)."""
        a0, a1 = sorted(along if along is not None else (self.foot, self.end))
        c0, c1 = across if across is not None else self.lane
        return Rect(a0, c0, a1, c1) if self.axis == 0 else Rect(c0, a0, c1, a1)

    def point(self, along: float, z: float) -> tuple[float, float, float]:
        c = (self.lane[0] + self.lane[1]) / 2
        return (along, c, z) if self.axis == 0 else (c, along, z)

    def steps(self, z0: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Solid step boxes ``(min, max)`` standing on ``z0``: step k spans tread k and rises to ``k * rise``."""
        out = []
        for k in range(1, self.n_risers):
            along = (self.foot + self.direction * (k - 1) * TREAD_M, self.foot + self.direction * k * TREAD_M)
            r = self.rect(along=along)
            out.append((np.array([r.x0, r.y0, z0]), np.array([r.x1, r.y1, round(z0 + k * self.rise, 6)])))
        return out


@dataclass
class Building:
    """Floors of plans (rooms, doorways, walls at z 0..height), their heights, and the flights between them."""

    kind: str
    plans: list[FloorPlan]
    floor_z: list[float]
    wall_height_m: float
    flights: list[Flight] = field(default_factory=list)
    hall: int = -1  # room index of the stair hall on every floor (-1: none)
    hall_rect: Rect | None = None

    def ceiling_z(self, floor: int) -> float:
        return round(self.floor_z[floor] + self.wall_height_m, 6)

    def openings(self, floor: int) -> list[Rect]:
        """Holes in ``floor`` (the flights from the floor below), reaching the hall's wall centre lines."""
        out = []
        for f in self.flights:
            if f.lower + 1 == floor and self.hall_rect is not None:
                h = self.hall_rect
                c_lo, c_hi = (h.y0, h.y1) if f.axis == 0 else (h.x0, h.x1)
                across = (c_lo, f.lane[1]) if f.lane[0] - c_lo < c_hi - f.lane[1] else (f.lane[0], c_hi)
                out.append(f.rect(across=across))
        return out

    def railings(self, floor: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Railing boxes around the openings of ``floor``: along the open long side and across the far end."""
        height, t = RAILING_M
        z0 = self.floor_z[floor]
        out = []
        for f, hole in zip([f for f in self.flights if f.lower + 1 == floor], self.openings(floor)):
            a0, a1 = sorted((f.foot, f.end))
            h = self.hall_rect
            c_lo = h.y0 if f.axis == 0 else h.x0
            inner = (f.lane[1], f.lane[1] + t) if abs(f.lane[0] - (c_lo + WALL_THICKNESS_M / 2)) < 1e-6 \
                else (f.lane[0] - t, f.lane[0])
            across = (hole.y0, hole.y1) if f.axis == 0 else (hole.x0, hole.x1)
            end = (f.foot - t, f.foot) if f.direction > 0 else (f.foot, f.foot + t)
            for r in (f.rect(across=inner, along=(a0, a1)), f.rect(across=across, along=end)):
                out.append((np.array([r.x0, r.y0, z0]), np.array([r.x1, r.y1, round(z0 + height, 6)])))
        return out

    def blocked(self, floor: int) -> list[Rect]:
        """What is not walkable floor on ``floor``: each flight rising from it, each opening in it."""
        return [f.rect() for f in self.flights if f.lower == floor] + self.openings(floor)

    def landings(self, floor: int, landing_m: float = 1.2) -> list[Rect]:
        """The hall's width for ``landing_m`` before the foot of each flight rising from ``floor`` and beyond the top
        of each flight arriving on it: floor furniture must leave free."""
        if self.hall_rect is None:
            return []
        h = self.hall_rect
        out = []
        for f in self.flights:
            across = (h.y0, h.y1) if f.axis == 0 else (h.x0, h.x1)
            if f.lower == floor:
                out.append(f.rect(across=across, along=(f.foot, f.foot - f.direction * landing_m)))
            if f.lower + 1 == floor:
                out.append(f.rect(across=across, along=(f.end, f.end + f.direction * landing_m)))
        return out

    def stair_spots(self, floor: int, off_m: float = 0.5) -> list[tuple[float, float]]:
        """Where the robot stands to take a flight on ``floor``: ``off_m`` before its foot or beyond its top."""
        out = []
        for f in self.flights:
            if f.lower == floor:
                out.append(f.point(f.foot - f.direction * off_m, 0.0)[:2])
            if f.lower + 1 == floor:
                out.append(f.point(f.end + f.direction * off_m, 0.0)[:2])
        return out


def rect_minus(r: Rect, hole: Rect) -> list[Rect]:
    """``r`` without ``hole`` as up to four rectangles (x bands, then the y bands between)."""
    x0, x1 = max(r.x0, hole.x0), min(r.x1, hole.x1)
    y0, y1 = max(r.y0, hole.y0), min(r.y1, hole.y1)
    if x0 >= x1 or y0 >= y1:
        return [r]
    out = [Rect(r.x0, r.y0, x0, r.y1), Rect(x1, r.y0, r.x1, r.y1), Rect(x0, r.y0, x1, y0), Rect(x0, y1, x1, r.y1)]
    return [p for p in out if p.w > 1e-9 and p.h > 1e-9]


def notched_polygon(r: Rect, hole: Rect) -> list[tuple[float, float]]:
    """Outline of ``r`` without ``hole``, counter-clockwise, where ``hole`` reaches one side of ``r`` (a stair
    opening against a wall): the rectangle with a notch."""
    x0, y0, x1, y1 = max(r.x0, hole.x0), max(r.y0, hole.y0), min(r.x1, hole.x1), min(r.y1, hole.y1)
    if abs(y0 - r.y0) < 1e-9:  # the notch cuts into the south side
        pts = [(r.x0, r.y0), (x0, r.y0), (x0, y1), (x1, y1), (x1, r.y0), (r.x1, r.y0), (r.x1, r.y1), (r.x0, r.y1)]
    elif abs(y1 - r.y1) < 1e-9:  # north
        pts = [(r.x0, r.y0), (r.x1, r.y0), (r.x1, r.y1), (x1, r.y1), (x1, y0), (x0, y0), (x0, r.y1), (r.x0, r.y1)]
    elif abs(x0 - r.x0) < 1e-9:  # west
        pts = [(r.x0, r.y0), (r.x1, r.y0), (r.x1, r.y1), (r.x0, r.y1), (r.x0, y1), (x1, y1), (x1, y0), (r.x0, y0)]
    elif abs(x1 - r.x1) < 1e-9:  # east
        pts = [(r.x0, r.y0), (r.x1, r.y0), (r.x1, y0), (x0, y0), (x0, y1), (r.x1, y1), (r.x1, r.y1), (r.x0, r.y1)]
    else:
        raise ValueError("a stair opening must reach a side of its room")
    out = []
    for p in pts:  # corners where the notch meets a room corner collapse
        if not out or np.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) > 1e-9:
            out.append((round(float(p[0]), 4), round(float(p[1]), 4)))
    return out[:-1] if len(out) > 1 and out[0] == out[-1] else out


def upper_types(rng: np.random.Generator, rooms: list[Rect]) -> list[str]:
    """Types of an upper floor's rooms: the largest a bedroom, the smallest a bathroom, the rest bedrooms and an
    office in random order."""
    n = len(rooms)
    by_area = sorted(range(n), key=lambda i: rooms[i].area)
    out = ["bedroom"] * n
    out[by_area[0]] = "bathroom"
    rest = ["office"] + ["bedroom"] * n
    for idx, t in zip(rng.permutation(by_area[1:-1]), rest):
        out[int(idx)] = t
    return out


def office_types(rng: np.random.Generator, rooms: list[Rect]) -> list[str]:
    """Half the rooms (the largest) open offices; one kitchen and one bathroom per ~12 rooms (the smallest are
    the bathrooms); the rest meeting rooms and offices in random order."""
    n = len(rooms)
    by_area = sorted(range(n), key=lambda i: rooms[i].area)
    n_bath = n_kitchen = max(1, n // 12)
    out = ["open office"] * n
    for i in by_area[:n_bath]:
        out[i] = "bathroom"
    middle = by_area[n_bath: n - n // 2]
    kinds = ["kitchen"] * n_kitchen + ["meeting room", "office"] * n
    for idx, t in zip(rng.permutation(middle), kinds):
        out[int(idx)] = t
    return out


def building_room_ids(plans: list[FloorPlan]) -> None:
    """``bedroom_1``, ``bedroom_2``... numbered floor by floor, each west to east then south to north (set in place)."""
    counts: dict[str, int] = {}
    for plan in plans:
        order = sorted(range(len(plan.rooms)), key=lambda i: (plan.rooms[i].x0, plan.rooms[i].y0))
        for i in order:
            key = plan.types[i].replace(" ", "_")
            counts[key] = counts.get(key, 0) + 1
            plan.ids[i] = f"{key}_{counts[key]}"


def generate_house(rng: np.random.Generator, stories: int, rooms_per_floor: tuple[int, int]) -> Building:
    """A house of ``stories`` floors (2 or 3), each with its stair hall plus ``rooms_per_floor`` (min, max) rooms."""
    height = round(float(rng.uniform(2.5, 2.7)), 2)
    story = height + SLAB_M
    n_risers = int(np.ceil(story / MAX_RISE_M))
    run = (n_risers - 1) * TREAD_M
    long_side = round(float(max(rng.uniform(10.0, 13.0), run + 2 * LANDING_M + 2 * WALL_THICKNESS_M)), 2)
    short_side = round(float(rng.uniform(7.5, 10.0)), 2)
    axis = int(rng.integers(2))  # the long side (and the flights) run along x (0) or y (1)
    outline = Rect(0.0, 0.0, long_side, short_side) if axis == 0 else Rect(0.0, 0.0, short_side, long_side)
    t = WALL_THICKNESS_M / 2
    slack = long_side - run - 2 * LANDING_M - 2 * t
    foot = round(float(t + LANDING_M + rng.uniform(0.0, slack)), 2)
    lanes = ((t, t + LANE_M), (t + LANE_M, t + 2 * LANE_M))
    flights = []
    for k in range(stories - 1):
        up = k % 2 == 0  # lane A climbs +a; lane B climbs back -a from the shared landing
        flights.append(Flight(k, axis, 1 if up else -1, foot if up else round(foot + run, 6), lanes[k % 2],
                              n_risers, round(story / n_risers, 6)))
    hall_rect = Rect(0.0, 0.0, long_side, HALL_M) if axis == 0 else Rect(0.0, 0.0, HALL_M, long_side)
    split = (1 - axis, HALL_M)  # the hall's inner wall: a line across the short side
    plans = []
    for floor in range(stories):
        n_rooms = int(rng.integers(rooms_per_floor[0], rooms_per_floor[1] + 1)) + 1  # + the hall
        landing = (0.0, foot) if floor == 0 or (floor - 1) % 2 == 1 else (foot + run, long_side)
        plan = split_plan(rng, outline, n_rooms, height, first_split=split, door_spans={0: landing})
        rooms = plan.rooms[1:]  # leaf 0 is the hall (the low side of the first split)
        types = assign_types(rng, rooms) if floor == 0 else upper_types(rng, rooms)
        plan.types = ["hallway"] + types
        plans.append(plan)
    building_room_ids(plans)
    return Building("house", plans, [round(k * story, 6) for k in range(stories)], height, flights, 0, hall_rect)


def generate_office(rng: np.random.Generator, size_m: tuple[float, float], room_area_m2: float) -> Building:
    """One office floor of ``size_m`` (x, y) split into rooms of about ``room_area_m2``, with extra doorways."""
    height = round(float(rng.uniform(2.7, 3.0)), 2)
    outline = Rect(0.0, 0.0, round(float(size_m[0]), 2), round(float(size_m[1]), 2))
    n_rooms = max(2, int(round(outline.area / room_area_m2)))
    plan = split_plan(rng, outline, n_rooms, height, extra_door_p=0.5)
    plan.types = office_types(rng, plan.rooms)
    building_room_ids([plan])
    return Building("office", [plan], [0.0], height)
