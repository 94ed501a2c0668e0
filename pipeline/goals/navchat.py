"""navchat's goal annotations (``objects.json``, ``final.json``) <-> zipon objects and goals.

navchat stores everything in cells of its 600x600 top-down grid: ``center`` is ``[x, z]`` =
``[col, row]``, ``contour`` an OpenCV contour ``[[[col, row]], ...]``, ``mass`` its area in cells.
Conversion uses a *stated* :class:`~pipeline.geometry.GridSpec` (the scene's recon grid, or the
grid the annotations were made on): cell (row, col) <-> the world position of its centre. ``|``
separates values (``room_info`` owners, ``object_desc``, ``nearby_obj``, ``same_goal``).
Round trip: :func:`export_navchat` of an imported set reproduces the input's cells exactly; zipon
names travel in an extra ``name`` key that navchat's loader ignores.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.geometry import GridSpec
from pipeline.goals.naming import ensure_unique
from pipeline.goals.objects import ObjectRecord, ObjectSet, RoomRecord, read_structured
from pipeline.goals.schema import Feedback, GoalEntry, GoalsDocument, ObjectEntry, RoomEntry


def _cells_to_world(grid: GridSpec, colrow: np.ndarray) -> np.ndarray:
    return grid.cell_to_world(np.asarray(colrow, dtype=np.float64)[..., ::-1])


def _world_to_colrow(grid: GridSpec, xy) -> np.ndarray:
    return grid.world_to_cell(np.asarray(xy, dtype=np.float64))[..., ::-1]


def _split(v) -> list[str]:
    return [s.strip() for s in str(v or "").split("|") if s.strip()]


def import_navchat(folder: Path, grid: GridSpec, scene: str) -> tuple[ObjectSet, GoalsDocument | None]:
    """Objects from ``objects.json`` (and goals from ``final.json`` when present) in ``folder``."""
    folder = Path(folder)
    objects_path, final_path = folder / "objects.json", folder / "final.json"
    raw_objs = read_structured(objects_path)
    final = read_structured(final_path) if final_path.is_file() else None
    if not isinstance(raw_objs, dict):
        raise InputDataError("expected a mapping of object keys", path=objects_path)
    goals_raw = {k: v for k, v in (final or {}).items() if k != "room_info"}
    objects = []
    for key, o in raw_objs.items():
        try:
            contour = np.asarray(o["contour"], dtype=np.int64).reshape(-1, 2)
            center = np.asarray(o["center"], dtype=np.int64)
            cls = str(o["name"])
        except (KeyError, TypeError, ValueError) as err:
            raise InputDataError(f"bad object record ({err})", path=objects_path, field=key,
                                 expected="{name, center: [col, row], mass, contour: [[[col, row]], ...]}") from None
        if len(contour) < 3:
            contour = np.array([center + d for d in ((0, 0), (1, 0), (1, 1), (0, 1))])
        g = goals_raw.get(key) or {}
        desc = _split(g.get("object_desc")) + ([str(g["explain"]).strip()] if g.get("explain") else [])
        objects.append(ObjectRecord(
            key=key, cls=cls, instance_id=0, room=g.get("room_id") or None,
            footprint=[tuple(p) for p in _cells_to_world(grid, contour).tolist()],
            mass_center=tuple(_cells_to_world(grid, center).tolist()),
            size="small" if g.get("type") == "small" else "big", description=desc,
        ))
    room_ids = sorted({o.room for o in objects if o.room})
    rooms = [RoomRecord(id=r, type=re.sub(r"_\d+$", "", r)) for r in room_ids]
    objset = ObjectSet(scene=scene, source="navchat", rooms=rooms, objects=objects)
    if final is None:
        return objset, None
    return objset, _goals_from_final(final, objset, final_path)


def _goals_from_final(final: dict, objset: ObjectSet, path: Path) -> GoalsDocument:
    by_key = objset.by_key()
    info = final.get("room_info") or {}
    rooms: dict[str, RoomEntry] = {}
    for r in objset.rooms:
        owners_all = [] if str(info.get(r.type, "shared")) == "shared" else _split(info.get(r.type))
        idx = int(r.id.rsplit("_", 1)[1]) - 1 if re.search(r"_\d+$", r.id) else 0
        owners = [owners_all[idx]] if idx < len(owners_all) else []
        rooms[r.id] = RoomEntry(type=r.type, owners=owners, name=f"{owners[0]}'s {r.type}" if owners else r.type)
    goals, names = [], {}
    for key, g in final.items():
        if key == "room_info":
            continue
        if key not in by_key:
            raise InputDataError(f"goal {key!r} is not in objects.json", path=path, field=key)
        o = by_key[key]
        room = rooms.get(o.room or "")
        name = g.get("name") or _navchat_name(o.cls, room, g.get("attr"))
        group = _split(g.get("same_goal")) or [key]
        group = [key] + sorted(k for k in group if k != key)
        names[key] = name
        landmarks = [k for k in _split(g.get("nearby_obj")) if k in by_key]
        lm = "It is near " + " and ".join(f"the {by_key[k].cls}" for k in landmarks) + "." if landmarks else ""
        gtype = g.get("type") if g.get("type") in ("big", "small", "ambiguous") else "big"
        goals.append(GoalEntry(id=key, name=name, type=gtype, room=room.name if room else None, room_id=o.room,
                               objects=group, feedback=Feedback(descriptive=" ".join(
                                   s.rstrip(".") + "." for s in _split(g.get("object_desc"))), landmark=lm)))
    ensure_unique([g.name for g in goals], "goal name")
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


def _navchat_name(cls: str, room: RoomEntry | None, attr) -> str:
    if room is not None and room.owners:
        return f"{room.owners[0]}'s {cls}"
    attr = str(attr or "").strip()
    if attr:
        return f"the {cls} {attr}" if attr.split()[0] in ("bought", "made", "from", "with") else f"the {attr}"
    return f"the {cls}"


def export_navchat(objset: ObjectSet, doc: GoalsDocument, grid: GridSpec, landmarks: dict | None = None
                   ) -> tuple[dict, dict]:
    """``(objects_json, final_json)`` dicts in navchat's layout, cells on ``grid``."""
    objects_json = {}
    for o in objset.objects:
        contour = _world_to_colrow(grid, o.footprint)
        objects_json[o.key] = {
            "name": o.cls,
            "center": [int(v) for v in _world_to_colrow(grid, o.mass_center)],
            "mass": float(cv2.contourArea(contour.reshape(-1, 1, 2).astype(np.int32))),
            "contour": [[[int(c), int(r)]] for c, r in contour],
        }
    room_info: dict[str, str] = {}
    for rid, r in sorted(doc.rooms.items()):
        if r.owners:
            prev = [] if room_info.get(r.type, "shared") == "shared" else room_info[r.type].split("|")
            room_info[r.type] = "|".join(prev + r.owners)
        else:
            room_info.setdefault(r.type, "shared")
    final: dict = {"room_info": room_info}
    for g in doc.goals:
        o = objects_json[g.id]
        near = [m["object"] for m in (landmarks or {}).get(g.id, [])]
        final[g.id] = {
            "base": json.dumps({"center": o["center"], "mass": o["mass"]}),
            "nearby_obj": "|".join(near),
            "object_desc": "|".join(s.strip() for s in g.feedback.descriptive.split(". ") if s.strip()).rstrip("."),
            "attr": None, "room_id": g.room_id, "explain": "", "type": g.type,
            "same_goal": "|".join(g.objects), "name": g.name,
        }
    return objects_json, final


def write_navchat(folder: Path, objects_json: dict, final_json: dict) -> None:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "objects.json").write_text(json.dumps(objects_json))
    (folder / "final.json").write_text(json.dumps(final_json, indent=2) + "\n")
