"""Personas and personalized names: room owners, manufacturers, purchase years, materials.

- Rooms: private rooms (bedrooms, offices) get one owner each ("Alice's bedroom"); the others
  are shared and named by their type (with a number when a type repeats: "bathroom 2").
- same_goal groups: instances of one class in one room with the same colour and material within
  ``radius_m`` of each other cannot be told apart; they share one identity and reaching any counts.
- Identity (every group, goal or not): "Alice's chair" in an owned room, else a persona attribute
  ("the chair bought from IKEA", "the bed bought in 2019", "the wooden table"); a qualifier is
  added until the name is unique in the scene. Persona attributes are drawn with the seed,
  distinct within a class, so names are always unique and reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import StageError
from pipeline.goals.objects import ObjectRecord, RoomRecord

NAMES = ("Alice", "Bob", "Carol", "David", "Emma", "Frank", "Grace", "Henry", "Irene", "Jack", "Kate", "Leo",
         "Maria", "Nina", "Oscar", "Paul")
COMPANIES = ("IKEA", "Amazon", "West Elm", "Walmart", "Target", "Wayfair", "Maiden Home", "Crate & Barrel",
             "Pottery Barn", "Costco", "Home Depot", "Best Buy", "Muji", "Herman Miller")
YEARS = tuple(range(2010, 2024))
MATERIAL_ADJECTIVES = {"wood": "wooden", "wooden": "wooden", "metal": "metal", "fabric": "fabric",
                       "leather": "leather", "plastic": "plastic", "glass": "glass", "ceramic": "ceramic",
                       "stone": "stone", "marble": "marble"}
OWNED_ROOM_TYPES = ("bedroom", "office", "study")


@dataclass(frozen=True)
class RoomInfo:
    id: str
    type: str
    owners: tuple[str, ...]  # empty = shared
    name: str  # "Alice's bedroom", "living room", "bathroom 2"


@dataclass
class Identity:
    """The personalized identity of one same_goal group."""

    name: str
    kind: str  # owner | manufacturer | date | material | owner+manufacturer | ...
    members: tuple[str, ...]  # object keys of the group
    owner: str | None = None
    manufacturer: str = ""
    purchase_year: int = 0
    extra: dict = field(default_factory=dict)


def assign_rooms(rooms: list[RoomRecord], rng: np.random.Generator) -> dict[str, RoomInfo]:
    """Owners for private rooms (distinct people), names for all rooms; unique room names."""
    people = list(NAMES)
    order = rng.permutation(len(people))
    people = [people[i] for i in order]
    by_type: dict[str, int] = {}
    for r in rooms:
        by_type[r.type] = by_type.get(r.type, 0) + 1
    seen: dict[str, int] = {}
    out = {}
    for r in sorted(rooms, key=lambda r: r.id):
        seen[r.type] = seen.get(r.type, 0) + 1
        if r.type in OWNED_ROOM_TYPES and people:
            owner = people.pop(0)
            out[r.id] = RoomInfo(r.id, r.type, (owner,), f"{owner}'s {r.type}")
        else:
            name = r.type if by_type[r.type] == 1 else f"{r.type} {seen[r.type]}"
            out[r.id] = RoomInfo(r.id, r.type, (), name)
    return out


def same_goal_groups(objects: list[ObjectRecord], radius_m: float) -> list[tuple[str, ...]]:
    """Groups of indistinguishable instances (same class, room, colour, material, within ``radius_m``).

    Returned sorted by first key; each group's keys sorted; singletons included.
    """
    keys = [o.key for o in objects]
    parent = list(range(len(objects)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    centers = np.array([o.mass_center for o in objects]) if objects else np.zeros((0, 2))
    sig = [(o.cls, o.room, o.color_name, o.material, o.floor) for o in objects]  # never across floors
    d = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    for i, j in zip(*np.nonzero(np.triu(d <= radius_m, 1))):
        if sig[i] == sig[j] and objects[i].room is not None and objects[i].color_name:
            parent[find(i)] = find(j)
    groups: dict[int, list[str]] = {}
    for i in range(len(objects)):
        groups.setdefault(find(i), []).append(keys[i])
    return sorted((tuple(sorted(g)) for g in groups.values()), key=lambda g: g[0])


def _article_name(cls: str, qualifier: str) -> str:
    return f"the {cls} {qualifier}"


def personalize(objects: list[ObjectRecord], rooms: dict[str, RoomInfo], groups: list[tuple[str, ...]],
                rng: np.random.Generator) -> dict[str, Identity]:
    """An :class:`Identity` per group (keyed by the group's first object key); names unique in the scene."""
    by_key = {o.key: o for o in objects}
    by_class: dict[str, list[tuple[str, ...]]] = {}
    for g in groups:
        by_class.setdefault(by_key[g[0]].cls, []).append(g)
    used: set[str] = set()
    out: dict[str, Identity] = {}
    for cls in sorted(by_class):
        cls_groups = by_class[cls]
        n = len(cls_groups)
        companies = [COMPANIES[i] for i in rng.permutation(len(COMPANIES))]
        years = [YEARS[i] for i in rng.permutation(len(YEARS))]
        materials = [by_key[g[0]].material for g in cls_groups]
        owners = [_owner(by_key[g[0]], rooms) for g in cls_groups]
        for i, g in enumerate(cls_groups):
            obj = by_key[g[0]]
            company = companies[i % len(companies)]
            year = years[(i // len(companies)) % len(years)] if n > len(companies) else years[i % len(years)]
            owner = owners[i]
            candidates: list[tuple[str, str]] = []
            if owner is not None:
                candidates.append(("owner", f"{owner}'s {cls}"))
                candidates.append(("owner+manufacturer", f"{owner}'s {cls} bought from {company}"))
            else:
                kinds = ["manufacturer", "date"]
                adj = MATERIAL_ADJECTIVES.get(obj.material.lower(), "")
                if adj and materials.count(obj.material) == 1:
                    kinds.append("material")
                kinds = [kinds[j] for j in rng.permutation(len(kinds))]
                for kind in kinds:
                    candidates.append((kind, {
                        "manufacturer": _article_name(cls, f"bought from {company}"),
                        "date": _article_name(cls, f"bought in {year}"),
                        "material": f"the {adj} {cls}",
                    }[kind]))
            candidates.append(("manufacturer+date", _article_name(cls, f"bought from {company} in {year}")))
            # an owned-room clash (two groups of a class in Alice's room) resolves by the manufacturer
            clash_owner = owner is not None and owners.count(owner) > 1
            for kind, name in candidates:
                if clash_owner and kind == "owner":
                    continue
                if name.lower() not in used:
                    break
            else:
                raise StageError(f"could not give {g[0]} a unique name (tried {[c[1] for c in candidates]})")
            used.add(name.lower())
            out[g[0]] = Identity(name=name, kind=kind, members=g, owner=owner, manufacturer=company,
                                 purchase_year=int(year))
    return out


def _owner(obj: ObjectRecord, rooms: dict[str, RoomInfo]) -> str | None:
    info = rooms.get(obj.room or "")
    return info.owners[0] if info is not None and info.owners else None


def ensure_unique(names: list[str], what: str = "name") -> None:
    """Raise :class:`StageError` naming the repeated names (case-insensitive)."""
    low = [n.lower() for n in names]
    dup = sorted({n for n, l in zip(names, low) if low.count(l) > 1})
    if dup:
        raise StageError(f"{what}s are not unique: {dup}")
