"""navchat's goal annotations (``objects.json``, ``final.json``) <-> zipon objects and goals, as navchat reads them.

navchat stores everything in cells of its 600x600 top-down grid: ``center`` is ``[x, z]`` =
``[col, row]``, ``contour`` an OpenCV contour ``[[[col, row]], ...]``, ``mass`` its area in cells;
``|`` separates values (``room_info`` owners, ``object_desc``, ``nearby_obj``, ``same_goal``).

**The grid is a stated frame** (:class:`NavchatFrame`, ``goals.navchat_grid``). navchat's own
(``orion/utils/geometry.py``, ``CoordinateTransform``) is anchored at the first recorded agent pose:
that position is cell ``(300, 300)``, columns grow to the agent's initial right, rows to its
initial backward direction, and a position maps to ``300 + int(d / 0.05)`` (truncation toward
zero; its voxel map rounds instead: ``rounding: round``). zipon takes the first pose of the
scene's ``frames.zarr`` (navchat's camera sits straight above its base, looking forward).
``origin: recon_grid`` reads cells on zipon's north-up recon grid instead.

**As navchat's loader** (``TopologicalGraph.load_instance_data``): a goal missing from
``objects.json`` is placed at its ``base`` (centre, mass; class from the key) and reported;
``same_goal`` members that are not objects are dropped and reported. Goal names keep the class
(``attr`` "Amazon basics" on a chair -> "the Amazon basics chair"). Objects whose footprint falls
outside the observed part of the recon grid are counted and reported
(:func:`outside_observed`); the goals stage refuses above ``goals.navchat_max_outside``.

**Round trip**: :func:`export_navchat` given the folder the goals were imported from writes every
record nothing was edited in exactly as navchat shipped it (``attr``, ``explain``, ``nearby_obj``,
``base``, ``room_info``, ``same_goal``, key order), and for edited goals changes only the edited
fields; ``json.dumps`` layout as navchat's files (``final.json`` indented by 2, no trailing newline).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import GridSpec, camera_yaw
from pipeline.goals.naming import ensure_unique
from pipeline.goals.objects import ObjectRecord, ObjectSet, RoomRecord, read_structured
from pipeline.goals.schema import Feedback, GoalEntry, GoalsDocument, ObjectEntry, RoomEntry

_VERB_ATTR = ("bought", "made", "from", "with", "special", "designed", "given", "built", "handmade", "owned")


# ----------------------------------------------------------------------------- the grid frame

@dataclass(frozen=True)
class NavchatFrame:
    """navchat grid cells ``(col, row)`` <-> world ``(x, y)``.

    Anchored frame (``grid is None``): ``origin_xy`` is cell ``anchor_cell``; a step of one column moves
    ``cell_size_m`` along ``right_xy``, one row along ``back_xy``. ``rounding`` 'trunc' (``int()``) or 'round'.
    With ``grid`` set, cells are zipon grid cells (row, col swapped to navchat's col, row).
    """

    origin_xy: tuple[float, float] = (0.0, 0.0)
    right_xy: tuple[float, float] = (1.0, 0.0)
    back_xy: tuple[float, float] = (0.0, -1.0)
    anchor_cell: tuple[int, int] = (300, 300)
    cell_size_m: float = 0.05
    rounding: str = "trunc"
    grid: GridSpec | None = None

    @classmethod
    def from_first_pose(cls, T_world_camera: np.ndarray, *, anchor_cell=(300, 300), cell_size_m: float = 0.05,
                        rounding: str = "trunc") -> "NavchatFrame":
        """navchat's frame for a recording whose first camera pose is ``T_world_camera`` ``(4,4)``."""
        yaw = float(camera_yaw(np.asarray(T_world_camera)))
        forward = (np.cos(yaw), np.sin(yaw))
        return cls(origin_xy=(float(T_world_camera[0, 3]), float(T_world_camera[1, 3])),
                   right_xy=(forward[1], -forward[0]), back_xy=(-forward[0], -forward[1]),
                   anchor_cell=tuple(int(v) for v in anchor_cell), cell_size_m=cell_size_m, rounding=rounding)

    @classmethod
    def from_grid(cls, grid: GridSpec) -> "NavchatFrame":
        return cls(grid=grid)

    def describe(self) -> str:
        if self.grid is not None:
            return "cells on the recon grid (north-up)"
        x, y = self.origin_xy
        return (f"navchat grid: cell {list(self.anchor_cell)} at world ({x:.3f}, {y:.3f}), columns toward "
                f"({self.right_xy[0]:+.3f}, {self.right_xy[1]:+.3f}), rows toward ({self.back_xy[0]:+.3f}, "
                f"{self.back_xy[1]:+.3f}), {self.cell_size_m} m cells, {self.rounding}")

    def to_world(self, colrow) -> np.ndarray:
        """``(...,2)`` cells -> ``(...,2)`` world x, y: the centre of the positions that map to each cell."""
        cr = np.asarray(colrow, dtype=np.float64)
        if self.grid is not None:
            return self.grid.cell_to_world(cr[..., ::-1])
        k = cr - np.asarray(self.anchor_cell, dtype=np.float64)
        if self.rounding == "trunc":  # int() maps (-1, 1) cells to 0: cell k>0 spans [k, k+1), k<0 (k-1, k]
            k = k + 0.5 * np.sign(k)
        d = k * self.cell_size_m
        return (np.asarray(self.origin_xy) + d[..., :1] * np.asarray(self.right_xy)
                + d[..., 1:] * np.asarray(self.back_xy))

    def to_cells(self, xy) -> np.ndarray:
        """``(...,2)`` world x, y -> ``(...,2)`` int64 cells ``(col, row)`` (navchat's rule)."""
        xy = np.asarray(xy, dtype=np.float64)
        if self.grid is not None:
            return self.grid.world_to_cell(xy)[..., ::-1]
        rel = xy - np.asarray(self.origin_xy)
        d = np.stack([rel @ np.asarray(self.right_xy), rel @ np.asarray(self.back_xy)], axis=-1) / self.cell_size_m
        k = np.trunc(d) if self.rounding == "trunc" else np.round(d)
        return (k + np.asarray(self.anchor_cell)).astype(np.int64)


def navchat_frame(settings, frames, recon_grid: GridSpec) -> NavchatFrame:
    """The frame ``goals.navchat_grid`` states: ``settings`` (its params), ``frames`` a FrameStore (first pose)."""
    if settings.origin == "recon_grid":
        return NavchatFrame.from_grid(recon_grid)
    if frames is None or frames.n_frames == 0:
        raise InputDataError("navchat_grid origin first_pose needs the scene's first camera pose",
                             field="goals.navchat_grid.origin", expected="an ingested frames.zarr")
    return NavchatFrame.from_first_pose(frames.group["pose"][0], anchor_cell=tuple(settings.anchor_cell),
                                        cell_size_m=settings.cell_size_m, rounding=settings.rounding)


def _as_frame(frame) -> NavchatFrame:
    return NavchatFrame.from_grid(frame) if isinstance(frame, GridSpec) else frame


# ----------------------------------------------------------------------------- import

def _split(v) -> list[str]:
    return [s.strip() for s in str(v or "").split("|") if s.strip()]


def _base(g: dict, key: str, path: Path) -> tuple[np.ndarray, float]:
    try:
        base = json.loads(g["base"]) if isinstance(g["base"], str) else g["base"]
        return np.asarray(base["center"], dtype=np.int64).reshape(2), float(base["mass"])
    except (KeyError, TypeError, ValueError) as err:
        raise InputDataError(f"goal is not in objects.json and its base is unreadable ({err})", path=path,
                             field=f"{key}.base", expected='a JSON string {"center": [col, row], "mass": m}') from None


def _square(center: np.ndarray) -> np.ndarray:
    return np.array([center + d for d in ((0, 0), (1, 0), (1, 1), (0, 1))])


def read_navchat(folder: Path) -> tuple[dict, dict | None]:
    """``(objects_json, final_json | None)`` as stored (key order kept)."""
    folder = Path(folder)
    objs = read_structured(folder / "objects.json")
    if not isinstance(objs, dict):
        raise InputDataError("expected a mapping of object keys", path=folder / "objects.json")
    final = read_structured(folder / "final.json") if (folder / "final.json").is_file() else None
    if final is not None and not isinstance(final, dict):
        raise InputDataError("expected a mapping of goal keys", path=folder / "final.json")
    return objs, final


def import_navchat(folder: Path, frame: NavchatFrame | GridSpec, scene: str, *,
                   log: Callable[[str], None] | None = None) -> tuple[ObjectSet, GoalsDocument | None]:
    """Objects from ``objects.json`` (and goals from ``final.json`` when present) in ``folder``, cells read in
    ``frame``. What navchat's loader would do silently (base fallback, unknown same_goal members) is logged."""
    folder, frame = Path(folder), _as_frame(frame)
    objects_path, final_path = folder / "objects.json", folder / "final.json"
    raw_objs, final = read_navchat(folder)
    goals_raw = {k: v for k, v in (final or {}).items() if k != "room_info"}
    records = []
    for key, o in raw_objs.items():
        try:
            contour = np.asarray(o["contour"], dtype=np.int64).reshape(-1, 2)
            center = np.asarray(o["center"], dtype=np.int64).reshape(2)
            records.append((key, str(o["name"]), contour, center))
        except (KeyError, TypeError, ValueError) as err:
            raise InputDataError(f"bad object record ({err})", path=objects_path, field=key,
                                 expected="{name, center: [col, row], mass, contour: [[[col, row]], ...]}") from None
    fallback = [k for k in goals_raw if k not in raw_objs]
    for key in fallback:  # navchat: name from the key, centre and mass from base, the centre as contour
        center, _ = _base(goals_raw[key], key, final_path)
        records.append((key, re.sub(r"_\d+$", "", key), center.reshape(1, 2), center))
    if fallback and log:
        log(f"navchat {final_path}: goals {fallback} are not in objects.json: placed at their base (centre, mass) "
            "as navchat's loader does")
    objects = []
    for key, cls, contour, center in records:
        if len(contour) < 3:
            contour = _square(center)
        g = goals_raw.get(key) or {}
        desc = _split(g.get("object_desc")) + ([str(g["explain"]).strip()] if g.get("explain") else [])
        objects.append(ObjectRecord(
            key=key, cls=cls, instance_id=0, room=g.get("room_id") or None,
            footprint=[tuple(p) for p in frame.to_world(contour).tolist()],
            mass_center=tuple(frame.to_world(center).tolist()),
            size="small" if g.get("type") == "small" else "big", description=desc,
        ))
    room_ids = sorted({o.room for o in objects if o.room})
    rooms = [RoomRecord(id=r, type=re.sub(r"_\d+$", "", r)) for r in room_ids]
    objset = ObjectSet(scene=scene, source="navchat", rooms=rooms, objects=objects)
    if final is None:
        return objset, None
    return objset, _goals_from_final(final, objset, final_path, log)


def _rooms(final: dict, objset: ObjectSet) -> dict[str, RoomEntry]:
    """navchat's room_mapping: ``room_info[type]`` split on '|', the i-th entry names ``{type}_{i+1}``."""
    info = final.get("room_info") or {}
    rooms: dict[str, RoomEntry] = {}
    for r in objset.rooms:
        owners_all = _split(info.get(r.type, "shared"))
        idx = int(r.id.rsplit("_", 1)[1]) - 1 if re.search(r"_\d+$", r.id) else 0
        owner = owners_all[idx] if idx < len(owners_all) else "shared"
        owners = [] if owner == "shared" else [owner]
        rooms[r.id] = RoomEntry(type=r.type, owners=owners, name=f"{owner}'s {r.type}" if owners else r.type)
    return rooms


def _goals_from_final(final: dict, objset: ObjectSet, path: Path, log) -> GoalsDocument:
    by_key = objset.by_key()
    rooms = _rooms(final, objset)
    goals, names, unknown = [], {}, {}
    for key, g in final.items():
        if key == "room_info":
            continue
        o = by_key[key]
        room = rooms.get(o.room or "")
        name = g.get("name") or navchat_name(o.cls, room, g.get("attr"))
        listed = _split(g.get("same_goal")) or [key]
        unknown.update({k: key for k in listed if k not in by_key})
        group = [key] + sorted(k for k in listed if k != key and k in by_key)
        names[key] = name
        landmarks = [k for k in _split(g.get("nearby_obj")) if k in by_key]
        lm = "It is near " + " and ".join(f"the {by_key[k].cls}" for k in landmarks) + "." if landmarks else ""
        gtype = g.get("type") if g.get("type") in ("big", "small", "ambiguous") else "big"
        goals.append(GoalEntry(id=key, name=name, type=gtype, room=room.name if room else None, room_id=o.room,
                               objects=group, feedback=Feedback(descriptive=_descriptive(g.get("object_desc")),
                                                                landmark=lm)))
    if unknown and log:
        log(f"navchat {path}: same_goal members {sorted(unknown)} are not objects (navchat: 'not in the graph'); "
            "left out of their groups")
    goals = _distinct_names(goals)
    ensure_unique([g.name for g in goals], "goal name")
    names = {g.id: g.name for g in goals}
    identities = {k: names.get(k, f"the {o.cls} ({k})") for k, o in by_key.items()}
    for g in goals:
        for k in g.objects:
            identities[k] = g.name
    goals = [g.model_copy(update={"feedback": g.feedback.model_copy(update={"corrective": {
        k: f"This is {identities[k]}, not {g.name}." for k in sorted(by_key)
        if by_key[k].cls == by_key[g.id].cls and k not in g.objects}})}) for g in goals]
    objects = {k: ObjectEntry(cls=o.cls, identity=identities[k], room=o.room,
                              position_xy=(round(o.mass_center[0], 3), round(o.mass_center[1], 3)))
               for k, o in sorted(by_key.items())}
    return GoalsDocument(scene=objset.scene, rooms=rooms, objects=objects, goals=goals)


def _distinct_names(goals: list[GoalEntry]) -> list[GoalEntry]:
    """Goals sharing a name (two racks, no attr) are told apart by their room, then by their key."""
    for suffix in (lambda g: f" in the {g.room}" if g.room else "", lambda g: f" ({g.id})"):
        low = [g.name.lower() for g in goals]
        goals = [g.model_copy(update={"name": g.name + suffix(g)}) if low.count(g.name.lower()) > 1 else g
                 for g in goals]
    return goals


def _descriptive(object_desc) -> str:
    return " ".join(s.rstrip(".") + "." for s in _split(object_desc))


def navchat_name(cls: str, room: RoomEntry | None, attr) -> str:
    """A goal's personalized name with its class: the room owner's, else from navchat's ``attr``."""
    if room is not None and room.owners:
        return f"{room.owners[0]}'s {cls}"
    attr = str(attr or "").strip()
    if not attr:
        return f"the {cls}"
    low, last = attr.lower(), cls.lower().split()[-1]
    if low.split()[0] in _VERB_ATTR:
        return f"the {cls} {attr}"  # "bought from IKEA" -> "the bed bought from IKEA"
    if low.endswith(cls.lower()) or low.endswith(last):
        return attr if "'s " in attr else f"the {attr}"  # "Maiden Home chair", "Alice's bookshelf"
    return f"the {attr} {cls}"  # "Amazon basics" -> "the Amazon basics chair"


# ----------------------------------------------------------------------------- coverage

def outside_observed(objset: ObjectSet, grid: GridSpec, observed: np.ndarray, min_fraction: float = 0.5
                     ) -> tuple[list[str], int, int]:
    """``(keys of objects with less than min_fraction of their footprint cells observed, observed object cells,
    object cells)`` on ``grid``; ``observed`` ``(rows, cols)`` bool. Cells off the grid count as unobserved."""
    outside, seen, total = [], 0, 0
    for o in objset.objects:
        rc = grid.world_to_cell(np.asarray(o.footprint))
        lo = rc.min(axis=0)
        local = np.zeros(tuple(rc.max(axis=0) - lo + 1), np.uint8)
        cv2.fillPoly(local, [(rc - lo)[:, ::-1].astype(np.int32).reshape(-1, 1, 2)], 1)
        cells = np.argwhere(local) + lo
        ins = grid.inside(cells)
        hit = int(observed[cells[ins, 0], cells[ins, 1]].sum())
        seen, total = seen + hit, total + len(cells)
        if hit < min_fraction * len(cells):
            outside.append(o.key)
    return outside, seen, total


# ----------------------------------------------------------------------------- export

def _object_record(o: ObjectRecord, frame: NavchatFrame) -> dict:
    contour = frame.to_cells(o.footprint)
    return {"name": o.cls, "center": [int(v) for v in frame.to_cells(o.mass_center)],
            "mass": float(cv2.contourArea(contour.reshape(-1, 1, 2).astype(np.int32))),
            "contour": [[[int(c), int(r)]] for c, r in contour]}


def export_navchat(objset: ObjectSet, doc: GoalsDocument, frame: NavchatFrame | GridSpec,
                   landmarks: dict | None = None, *, source: Path | None = None) -> tuple[dict, dict]:
    """``(objects_json, final_json)`` dicts in navchat's layout, cells in ``frame``.

    ``source``: the navchat folder the goals were imported from; records nothing was edited in are written
    exactly as there, edited goals change only their edited fields (see the module doc).
    """
    frame = _as_frame(frame)
    src_objs, src_final = read_navchat(source) if source is not None else ({}, None)
    src_final = src_final or {}
    if source is not None:
        base_set, base_doc = import_navchat(source, frame, objset.scene)
        base_objs = base_set.by_key()
        base_goals = {g.id: g for g in base_doc.goals} if base_doc else {}
        base_rooms = base_doc.rooms if base_doc else None
    else:
        base_objs, base_goals, base_rooms = {}, {}, None
    objects_json = {}
    for o in objset.objects:
        rec = _object_record(o, frame)
        b = base_objs.get(o.key)
        same = (o.key in src_objs and b is not None and b.cls == o.cls
                and _object_record(b, frame)["contour"] == rec["contour"]
                and _object_record(b, frame)["center"] == rec["center"])
        if same:
            objects_json[o.key] = src_objs[o.key]
        elif o.key not in src_objs and o.key in src_final and b is not None and \
                _object_record(b, frame)["center"] == rec["center"]:
            continue  # a base-fallback goal stays out of objects.json, as shipped
        else:
            objects_json[o.key] = rec
    if base_rooms is not None and base_rooms == doc.rooms and "room_info" in src_final:
        room_info = src_final["room_info"]
    else:
        room_info = _room_info(doc.rooms)
    final: dict = {"room_info": room_info}
    for g in doc.goals:
        if g.id in src_objs:
            unchanged = objects_json.get(g.id) is src_objs[g.id]
        else:
            unchanged = g.id in src_final and g.id not in objects_json
        final[g.id] = _goal_record(g, src_final.get(g.id), base_goals.get(g.id), unchanged, objset, frame, landmarks)
    return objects_json, final


def _room_info(rooms: dict[str, RoomEntry]) -> dict[str, str]:
    """navchat's room_info: per type, the owner of ``{type}_{i}`` at position i-1 ('shared' when none)."""
    by_type: dict[str, dict[int, str]] = {}
    for rid, r in rooms.items():
        idx = int(rid.rsplit("_", 1)[1]) if re.search(r"_\d+$", rid) else 1
        by_type.setdefault(r.type, {})[idx] = r.owners[0] if r.owners else "shared"
    return {t: "|".join(v.get(i, "shared") for i in range(1, max(v) + 1)) for t, v in by_type.items()}


def _goal_record(g: GoalEntry, original: dict | None, imported: GoalEntry | None, unchanged_geometry: bool,
                 objset: ObjectSet, frame: NavchatFrame, landmarks: dict | None) -> dict:
    """final.json record of ``g``: the ``original`` with only what was edited since import changed, or a new one."""
    cells = _object_record(objset.by_key()[g.id], frame)
    base = json.dumps({"center": cells["center"], "mass": cells["mass"]})
    if original is not None and imported is not None:
        rec = dict(original)
        edits = {"base": (not unchanged_geometry, base), "type": (g.type != imported.type, g.type),
                 "room_id": (g.room_id != imported.room_id, g.room_id),
                 "same_goal": (g.objects != imported.objects, "|".join(g.objects)),
                 "object_desc": (g.feedback.descriptive != imported.feedback.descriptive,
                                 _object_desc(g.feedback.descriptive)),
                 "name": (g.name != imported.name, g.name)}
        rec.update({k: v for k, (edited, v) in edits.items() if edited})
        return rec
    near = [m["object"] for m in (landmarks or {}).get(g.id, [])]
    return {"base": base, "nearby_obj": "|".join(near), "object_desc": _object_desc(g.feedback.descriptive),
            "attr": None, "room_id": g.room_id, "explain": "", "type": g.type, "same_goal": "|".join(g.objects),
            "name": g.name}


def _object_desc(descriptive: str) -> str:
    return "|".join(s.strip().rstrip(".") for s in re.split(r"(?<=\.)\s+", descriptive) if s.strip())


def write_navchat(folder: Path, objects_json: dict, final_json: dict) -> None:
    """The two files laid out as navchat ships them (``json.dumps``; final.json indented by 2)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "objects.json").write_text(json.dumps(objects_json))
    (folder / "final.json").write_text(json.dumps(final_json, indent=2))


def check_navchat_coverage(objset: ObjectSet, grid: GridSpec, observed: np.ndarray, max_outside: float, *,
                           path=None, log: Callable[[str], None] = print) -> dict:
    """Count navchat objects outside the observed map; warn, or refuse above ``max_outside`` (a fraction)."""
    outside, seen, total = outside_observed(objset, grid, observed)
    n = len(objset.objects)
    report = {"objects": n, "objects_outside_observed": outside, "object_cells": total, "object_cells_observed": seen}
    if outside and len(outside) > max_outside * n:
        raise InputDataError(
            f"{len(outside)} of {n} navchat objects lie outside the observed map ({seen} of {total} object cells "
            f"observed), e.g. {outside[:5]}", path=path, field="goals.navchat_grid",
            expected=f"at most goals.navchat_max_outside = {max_outside} of them: the grid the files were made on "
                     "(origin first_pose for navchat's recordings, recon_grid for cells on zipon's grid)")
    if outside:
        log(f"navchat: {len(outside)} of {n} objects lie outside the observed map ({seen} of {total} object cells "
            f"observed): {outside}")
    return report


def export_scene(goals, settings, frames, scene: str, root: Path) -> tuple[dict, dict]:
    """``zipon goals export-navchat``: a built scene's goals (``goals`` a :class:`pipeline.goals.store.Goals`) in
    the frame ``settings.navchat_grid`` states (``frames`` its FrameStore or None), merged losslessly with the
    navchat folder the scene's goals were imported from (``settings.navchat_dirs[scene]`` under ``root``)."""
    source = None
    if goals.meta.source == "navchat" and scene in settings.navchat_dirs:
        source = Path(root) / settings.navchat_dirs[scene]
    frame = navchat_frame(settings.navchat_grid, frames, goals.grid)
    return export_navchat(goals.object_set(), goals.document, frame, goals.meta.landmarks, source=source)
