"""Floor plans: an apartment rectangle split (binary space partition) into rectangular rooms.

Every split line becomes a wall with one doorway between a room on each side, so the doorway
graph is a spanning tree of the rooms: every room is reachable. Walls are boxes of
``WALL_THICKNESS_M`` centred on the split lines and on the outline; a lintel closes each
doorway above ``DOOR_HEIGHT_M`` so depth stays valid upward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

WALL_THICKNESS_M = 0.1
DOOR_HEIGHT_M = 2.05
MIN_ROOM_SIDE_M = 2.4

# Room types in the order they are handed out (the largest room is the living room, the
# smallest the bathroom; see assign_types).
ROOM_TYPES = ("living room", "kitchen", "bathroom", "bedroom", "bedroom", "office", "bedroom", "bathroom",
              "office", "bedroom")


@dataclass
class Rect:
    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def w(self) -> float:
        return self.x1 - self.x0

    @property
    def h(self) -> float:
        return self.y1 - self.y0

    @property
    def area(self) -> float:
        return self.w * self.h


@dataclass
class Door:
    """A doorway on an axis-aligned wall line: ``axis`` 0 = wall along y at x=``at``; 1 = along x at y=``at``."""

    axis: int
    at: float
    lo: float
    hi: float
    rooms: tuple[int, int]
    split: int = -1  # index of the split line it pierces

    @property
    def center_xy(self) -> tuple[float, float]:
        mid = (self.lo + self.hi) / 2
        return (self.at, mid) if self.axis == 0 else (mid, self.at)


@dataclass
class FloorPlan:
    outline: Rect
    rooms: list[Rect]
    types: list[str]
    ids: list[str]
    doors: list[Door]
    wall_height_m: float
    walls: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (min, max) boxes


def _split_leaves(rng: np.random.Generator, outline: Rect, n_rooms: int, first_split: tuple[int, float] | None = None):
    """Split the largest splittable leaf until ``n_rooms`` leaves; returns leaves, their path labels and the split
    records. ``first_split`` ``(axis, at)`` is made first, without randomness, and its side ``a`` (the low side) is
    kept whole (a house's stair hall)."""
    leaves = [outline]
    splits = []  # (axis, at, extent lo, extent hi, leaf-index sets filled later)
    # Track which leaves descend from each side of each split by giving leaves a path label.
    labels = [""]
    whole = set()  # labels of leaves never split
    if first_split is not None:
        axis, at = first_split
        r = outline
        a, b = (Rect(r.x0, r.y0, at, r.y1), Rect(at, r.y0, r.x1, r.y1)) if axis == 0 else \
            (Rect(r.x0, r.y0, r.x1, at), Rect(r.x0, at, r.x1, r.y1))
        splits.append((axis, at, r.y0, r.y1, "") if axis == 0 else (axis, at, r.x0, r.x1, ""))
        leaves, labels, whole = [a, b], ["a", "b"], {"a"}
    while len(leaves) < n_rooms:
        order = sorted(range(len(leaves)), key=lambda i: -leaves[i].area)
        for i in order:
            r = leaves[i]
            if labels[i] in whole:
                continue
            axis = 0 if r.w >= r.h else 1  # split across the longer side
            length = r.w if axis == 0 else r.h
            if length < 2 * MIN_ROOM_SIDE_M:
                axis = 1 - axis
                length = r.w if axis == 0 else r.h
                if length < 2 * MIN_ROOM_SIDE_M:
                    continue
            lo = max(0.35, MIN_ROOM_SIDE_M / length)
            frac = rng.uniform(lo, 1 - lo)
            if axis == 0:
                at = round(r.x0 + frac * r.w, 2)
                a, b = Rect(r.x0, r.y0, at, r.y1), Rect(at, r.y0, r.x1, r.y1)
                splits.append((0, at, r.y0, r.y1, labels[i]))
            else:
                at = round(r.y0 + frac * r.h, 2)
                a, b = Rect(r.x0, r.y0, r.x1, at), Rect(r.x0, at, r.x1, r.y1)
                splits.append((1, at, r.x0, r.x1, labels[i]))
            leaves[i:i + 1] = [a, b]
            labels[i:i + 1] = [labels[i] + "a", labels[i] + "b"]
            break
        else:
            break  # nothing left to split
    return leaves, labels, splits


def _place_doors(rng: np.random.Generator, leaves: list[Rect], labels: list[str], splits,
                 spans: dict[int, tuple[float, float]] | None = None, extra_door_p: float = 0.0) -> list[Door]:
    """One doorway per split line between a room on each side (a spanning tree of the rooms). ``spans`` limits the
    doorway of a split (by index) to a stretch of its line; with ``extra_door_p`` > 0 every other pair of rooms
    sharing a split line gets a doorway too with that probability (loops, as in an office floor)."""
    doors = []
    for k, (axis, at, _, _, label) in enumerate(splits):
        side_a = [i for i, lab in enumerate(labels) if lab.startswith(label + "a")]
        side_b = [i for i, lab in enumerate(labels) if lab.startswith(label + "b")]
        candidates = []
        for i in side_a:
            for j in side_b:
                ri, rj = leaves[i], leaves[j]
                if axis == 0 and abs(ri.x1 - at) < 1e-6 and abs(rj.x0 - at) < 1e-6:
                    lo, hi = max(ri.y0, rj.y0), min(ri.y1, rj.y1)
                elif axis == 1 and abs(ri.y1 - at) < 1e-6 and abs(rj.y0 - at) < 1e-6:
                    lo, hi = max(ri.x0, rj.x0), min(ri.x1, rj.x1)
                else:
                    continue
                if spans is not None and k in spans:
                    lo, hi = max(lo, spans[k][0]), min(hi, spans[k][1])
                if hi - lo >= 1.4:
                    candidates.append((i, j, lo, hi))
        if not candidates:
            raise RuntimeError("floor plan without a doorway candidate")  # cannot happen with MIN_ROOM_SIDE_M
        chosen = [int(rng.integers(len(candidates)))]
        if extra_door_p > 0:
            chosen += [c for c in range(len(candidates)) if c != chosen[0] and rng.random() < extra_door_p]
        for c in chosen:
            i, j, lo, hi = candidates[c]
            # a doorway keeps 0.25 m of wall either side: on a 1.4-1.55 m shared wall it narrows (not below 0.9 m),
            # to the centimetre below what is left (rounded up, the door would not fit: 1.409 m leaves 0.909, not 0.91)
            room = hi - lo - 0.5
            width = min(round(float(rng.uniform(0.9, 1.05)), 2), round(room, 2))
            if width > room:
                width = math.floor(room * 100.0) / 100.0
            start = round(float(rng.uniform(lo + 0.25, hi - 0.25 - width)), 2)
            doors.append(Door(axis, at, start, start + width, (i, j), k))
    return doors


def _wall_boxes(outline: Rect, splits, doors: list[Door], height: float):
    """Wall boxes (min, max): the outline and every split line, with doorway gaps and lintels."""
    t = WALL_THICKNESS_M / 2
    lines = [(0, outline.x0, outline.y0 - t, outline.y1 + t, -1), (0, outline.x1, outline.y0 - t, outline.y1 + t, -1),
             (1, outline.y0, outline.x0 - t, outline.x1 + t, -1), (1, outline.y1, outline.x0 - t, outline.x1 + t, -1)]
    lines += [(axis, at, lo, hi, k) for k, (axis, at, lo, hi, _) in enumerate(splits)]
    boxes = []
    for axis, at, lo, hi, k in lines:
        gaps = sorted((d.lo, d.hi) for d in doors if k >= 0 and d.split == k)
        cursor = lo
        segments = []
        for g0, g1 in gaps:
            segments.append((cursor, g0, 0.0, height))
            segments.append((g0, g1, DOOR_HEIGHT_M, height))  # lintel
            cursor = g1
        segments.append((cursor, hi, 0.0, height))
        for s0, s1, z0, z1 in segments:
            if s1 - s0 < 1e-6:
                continue
            if axis == 0:
                boxes.append((np.array([at - t, s0, z0]), np.array([at + t, s1, z1])))
            else:
                boxes.append((np.array([s0, at - t, z0]), np.array([s1, at + t, z1])))
    return boxes


def assign_types(rng: np.random.Generator, rooms: list[Rect]) -> list[str]:
    """Largest room -> living room, smallest -> bathroom, the rest from :data:`ROOM_TYPES` in random order."""
    n = len(rooms)
    # The middle rooms take the other types in ROOM_TYPES order (extra rooms are bedrooms).
    others = list(ROOM_TYPES)
    others.remove("living room")
    others.remove("bathroom")  # the first one; a large apartment keeps its second bathroom
    rest = (others + ["bedroom"] * n)[: max(n - 2, 0)]
    by_area = sorted(range(n), key=lambda i: rooms[i].area)
    out = [""] * n
    out[by_area[-1]] = "living room"
    out[by_area[0]] = "bathroom"
    order = rng.permutation(by_area[1:-1])
    for idx, t in zip(order, rest):
        out[int(idx)] = t
    return out


def room_ids(types: list[str], rooms: list[Rect]) -> list[str]:
    """``bedroom_1``, ``bedroom_2``... numbered west to east, then south to north (stable for a plan)."""
    order = sorted(range(len(rooms)), key=lambda i: (rooms[i].x0, rooms[i].y0))
    counts: dict[str, int] = {}
    ids = [""] * len(rooms)
    for i in order:
        key = types[i].replace(" ", "_")
        counts[key] = counts.get(key, 0) + 1
        ids[i] = f"{key}_{counts[key]}"
    return ids


def generate_floor_plan(rng: np.random.Generator, n_rooms: int, *, size_range_m=(8.0, 15.0)) -> FloorPlan:
    """A random apartment of ``n_rooms`` rectangular rooms (outline ``size_range_m`` along its longer side)."""
    area_per_room = rng.uniform(14.0, 19.0)
    long_side = float(np.clip(np.sqrt(n_rooms * area_per_room * rng.uniform(1.3, 1.7)), *size_range_m))
    short_side = float(np.clip(n_rooms * area_per_room / long_side, 2 * MIN_ROOM_SIDE_M, long_side))
    w, h = (long_side, short_side) if rng.random() < 0.5 else (short_side, long_side)
    outline = Rect(0.0, 0.0, round(w, 2), round(h, 2))
    leaves, labels, splits = _split_leaves(rng, outline, n_rooms)
    doors = _place_doors(rng, leaves, labels, splits)
    types = assign_types(rng, leaves)
    height = round(float(rng.uniform(2.5, 2.8)), 2)
    plan = FloorPlan(outline, leaves, types, room_ids(types, leaves), doors, height)
    plan.walls = _wall_boxes(outline, splits, doors, height)
    return plan


def split_plan(rng: np.random.Generator, outline: Rect, n_rooms: int, height: float, *,
               first_split: tuple[int, float] | None = None, door_spans: dict[int, tuple[float, float]] | None = None,
               extra_door_p: float = 0.0) -> FloorPlan:
    """A floor of ``outline`` split into ``n_rooms`` rooms with doorways and walls ``height`` high; types and ids are
    left for the caller (a building names its rooms across floors). See :func:`_split_leaves` and
    :func:`_place_doors` for ``first_split``, ``door_spans`` and ``extra_door_p``."""
    leaves, labels, splits = _split_leaves(rng, outline, n_rooms, first_split)
    doors = _place_doors(rng, leaves, labels, splits, door_spans, extra_door_p)
    plan = FloorPlan(outline, leaves, [""] * len(leaves), [""] * len(leaves), doors, height)
    plan.walls = _wall_boxes(outline, splits, doors, height)
    return plan
