"""What the annotation page shows of one scene, read from its built artifacts: the top-down layers as PNG, the
objects, goals (numbered as ``zipon render --what goals`` numbers them), routes and camera trajectory as JSON in
world metres, the frames that saw a place, map-query proposals, procedural-route previews, and warnings on
descriptive feedback that contradicts its object.

A building's floors (:mod:`zipon.annotate.floors`): layers, the frames that saw a place and proposals are read per
floor; objects, rooms, goals, routes (leg by leg) and the trajectory carry their floor; the route preview crosses
floors over the stairs. A single-floor scene is floor 0 throughout."""

from __future__ import annotations

import math
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import cv2
import numpy as np

from pipeline.errors import InputDataError
from pipeline.region import region_window
from zipon.annotate.floors import (building_route, check_floor, floor_records, recorded_start_floor, rounded,
                                   stair_records)
from zipon.annotate.layers import LAYERS, Picture, height_top, paint, stride_for

PICTURES_KEPT = 8  # layer pictures kept per scene (the page asks again for the window it shows as it pans)
TRAJECTORY_POINTS = 400  # at most this many camera poses are sent (evenly spaced)
SEEN_MAX = 6  # frames listed for a clicked place
SEEN_TOLERANCE_M = 0.15  # a frame saw the place when its depth there is within this of the distance


@dataclass
class SceneView:
    """The annotation page's reading of one scene (a :class:`zipon.Scene`); cached per server, dropped on save."""

    scene: object  # zipon.Scene
    _cache: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.scene.name

    def has(self, artifact: str) -> bool:
        return self.scene.workspace.artifact(artifact, self.name).exists()

    def _get(self, key, make):
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    @property
    def recon(self):
        return self._get("recon", lambda: self.scene.recon)

    @property
    def goals(self):
        return self._get("goals", lambda: self.scene.goals if self.has("goals") else None)

    @property
    def frames(self):
        return self._get("frames", lambda: self.scene.frames if self.has("frames") else None)

    def summary(self) -> dict:
        """Grid, layers, rooms, objects, goals, routes and trajectory, all in world metres."""
        recon = self.recon
        grid = recon.grid
        goals = self.goals
        building = len(recon.floors) > 1
        out = {
            "scene": self.name,
            "grid": {"rows": grid.rows, "cols": grid.cols, "cell_size_m": grid.cell_size_m,
                     "origin_xy": list(grid.origin_xy), "extent_xy": list(grid.extent_xy),
                     "observed_xy": self._observed_xy()},
            "floor_z": float(recon.meta.floor_z),
            "floors": floor_records(recon), "stairs": stair_records(recon),
            "layers": [name for name in LAYERS if name != "rooms" or self._rooms()],
            "maps": [m for m in ("vlmap", "cfmap") if self.has(m)],
            "rooms": self._rooms(),
            "objects": [], "goals": [], "routes": [], "ground_truth": False,
            "trajectory": self._trajectory(),
        }
        if goals is not None:
            out["objects"] = [_object_json(o) for o in goals.objects.values()]
            out["ground_truth"] = goals.meta.source == "gt"
            out["goals"] = [{"number": k, "id": g.id, "name": g.name, "type": g.type, "room_id": g.room_id,
                             "floor": g.floor,
                             "objects": list(g.object_keys), "mass_center": [float(v) for v in g.mass_center],
                             "landmarks": [lm["object"] for lm in g.landmarks if "object" in lm]}
                            for k, g in enumerate(goals.goals, 1)]
        if self.has("routes"):
            routes = self.scene.routes
            out["routes"] = [{"id": e.id, "goal_id": e.goal_id, "start": [float(v) for v in e.start],
                              "path": _rounded(e.path_xy), "start_floor": e.start_floor,
                              "legs": [{"floor": f, "path": _rounded(xy)} for f, xy in e.legs()]}
                             for e in routes.episodes]
        if building:  # each camera pose's floor, as a 4th value
            floor_of = recon.floor_of_z(recon.poses[:, 2, 3])
            idx = self._trajectory_index()
            out["trajectory"] = [[*p, int(floor_of[i])] for p, i in zip(out["trajectory"], idx)]
        return out

    def _rooms(self) -> list[dict]:
        goals = self.goals
        if goals is None:
            return []
        outlines = self._get("room_outlines", self._room_outlines)
        rooms = goals.document.rooms
        # a room's floor: its outline's, else that of an object standing in it
        floor_of = {o.room: o.floor for o in reversed(list(goals.objects.values())) if o.room}
        return [{"id": rid, "type": r.type, "name": r.name, "owners": list(r.owners),
                 "polygon": [list(p) for p in outlines.get(rid, ([], 0))[0]],
                 "floor": outlines[rid][1] if rid in outlines else floor_of.get(rid, 0)} for rid, r in rooms.items()]

    def _observed_rc(self) -> tuple[int, int, int, int]:
        """``(row0, row1, col0, col1)`` (ends excluded) of the observed cells of every floor (the floors share one
        grid placement, so the page keeps its view when the floor changes), found tile by tile: the whole grid when
        none are."""
        from pipeline.recon.render import observed_window

        boxes = [w for w in (observed_window(self.recon.floor(k), margin=0) for k in range(len(self.recon.floors)))
                 if w is not None]
        if not boxes:
            return 0, self.recon.grid.rows, 0, self.recon.grid.cols
        return (min(w.r0 for w in boxes), max(w.r1 for w in boxes), min(w.c0 for w in boxes),
                max(w.c1 for w in boxes))

    def _observed_xy(self) -> list[float]:
        """``(x_min, x_max, y_min, y_max)`` of the observed cells (what the page fits to), metres."""
        grid = self.recon.grid
        r0, r1, c0, c1 = self._get("observed_rc", self._observed_rc)
        x0, y1 = grid.origin_xy
        c = grid.cell_size_m
        return [x0 + c0 * c, x0 + c1 * c, y1 - r1 * c, y1 - r0 * c]

    def _room_outlines(self) -> dict[str, tuple[list, int]]:
        """Room id -> (floor outline, floor): the simulator's ground truth, else the scene's objects file."""
        frames = self.frames
        gt = frames.ground_truth if frames is not None else None
        rooms = gt.rooms if gt is not None else getattr(self.objects_file(), "rooms", [])
        return {r.id: ([list(map(float, p)) for p in r.polygon], int(r.floor)) for r in rooms}

    def objects_file(self):
        """The scene's objects file (``goals.objects_files.<scene>``) as an ObjectSet, or None when it has none."""
        from pipeline.goals.objects import objects_from_file

        sc = self.scene
        rel = sc.params.goals.objects_files.get(self.name)
        if rel is None or not (sc.workspace.root / rel).is_file():
            return None
        return objects_from_file(sc.workspace.root / rel, self.name)

    def _trajectory_index(self) -> np.ndarray:
        n = len(self.recon.poses)
        return np.unique(np.linspace(0, n - 1, min(n, TRAJECTORY_POINTS)).round().astype(int)) if n else \
            np.zeros(0, int)

    def _trajectory(self) -> list[list[float]]:
        poses = self.recon.poses
        if len(poses) == 0:
            return []
        idx = self._trajectory_index()
        xy = poses[idx, :2, 3]
        fwd = poses[idx, :2, 2]  # the camera's optical axis (z) on the floor plane
        yaw = np.arctan2(fwd[:, 1], fwd[:, 0])
        return [[round(float(x), 3), round(float(y), 3), round(float(a), 3)] for (x, y), a in zip(xy, yaw)]

    # ------------------------------------------------------------------------- layers

    def warm(self) -> None:
        """Read what every layer picture of the scene shares (each floor's brightest height), so the page's first
        pictures (of the windows it shows, unknown before it asks) wait for none of it."""
        for floor in range(len(self.recon.floors)):
            level = self.recon.floor(floor)
            self._get(("height_top", floor), lambda level=level: height_top(level))

    def layer_png(self, name: str, floor: int = 0) -> bytes:
        """The whole grid of floor ``floor`` as one layer, one pixel per cell (see :meth:`layer`)."""
        return self.layer(name, floor)[0]

    def layer(self, name: str, floor: int = 0, region=None, px: int | None = None) -> tuple[bytes, Picture]:
        """Layer ``name`` of floor ``floor`` as a PNG and what it covers (:mod:`zipon.annotate.layers`): the cells
        of ``region`` (a :class:`~pipeline.region.Region`; the whole grid for None) at most ``px`` pixels on the
        longer side, painted from the recon tiles the region meets. The last few pictures are kept."""
        if name not in LAYERS:
            raise InputDataError(f"unknown layer {name!r}", field="layer", expected=f"one of {list(LAYERS)}")
        check_floor(self.recon, self.name, floor)
        level = self.recon.floor(floor)
        window = region_window(level.grid, region, "region")
        stride = stride_for(window, px)
        key = (name, floor, window, stride)
        pictures, lock = self._get("pictures", OrderedDict), self._get("pictures_lock", threading.Lock)
        with lock:  # requests are served from a thread pool
            if key in pictures:
                pictures.move_to_end(key)
                return pictures[key]
        top = self._get(("height_top", floor), lambda: height_top(level)) if name == "height" else 1.0
        rooms = [r for r in self._rooms() if len(r["polygon"]) >= 3 and r["floor"] == floor] if name == "rooms" \
            else []
        picture = paint(level, name, window, stride, top_m=top, rooms=rooms)
        done = (_png(picture.rgba), picture)
        with lock:
            pictures[key] = done
            while len(pictures) > PICTURES_KEPT:
                pictures.popitem(last=False)
        return done

    # ------------------------------------------------------------------------- frames that saw a place

    def seen(self, x: float, y: float, floor: int = 0) -> dict:
        """Frames whose camera saw the world point (x, y) on the top surface there (of floor ``floor``): its
        projection falls in the image and the depth there agrees with the distance (so a wall or a slab in between
        rules the frame out). The nearest views first."""
        frames = self.frames
        if frames is None:
            raise InputDataError(f"scene {self.name} has no frames.zarr", field="frames")
        level = self.recon.floor(check_floor(self.recon, self.name, floor))
        grid = level.grid
        rc = grid.world_to_cell(np.array([x, y]))
        if not grid.inside(rc):
            raise InputDataError(f"({x:g}, {y:g}) is off the map", field="x,y",
                                 expected=f"a point inside {[round(v, 2) for v in grid.extent_xy]}")
        h = self._get(("height", floor), lambda: level.height)[int(rc[0]), int(rc[1])]
        z = float(level.floor_z) + (float(h) if np.isfinite(h) else 0.0)
        point = np.array([x, y, z, 1.0])
        poses = self._get("poses", frames.poses)
        cam = np.einsum("nij,j->ni", np.linalg.inv(poses), point)[:, :3]
        intr = frames.intrinsics
        ahead = cam[:, 2] > 0.05
        u = np.where(ahead, intr.fx * cam[:, 0] / np.where(ahead, cam[:, 2], 1) + intr.cx, -1)
        v = np.where(ahead, intr.fy * cam[:, 1] / np.where(ahead, cam[:, 2], 1) + intr.cy, -1)
        inside = ahead & (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
        found = []
        for i in np.flatnonzero(inside)[np.argsort(cam[inside, 2], kind="stable")]:
            depth = float(frames.group["depth"][int(i), int(v[i]), int(u[i])]) / 1000.0
            if depth > 0 and abs(depth - cam[i, 2]) <= SEEN_TOLERANCE_M + 0.05 * cam[i, 2]:
                found.append({"frame": int(i), "distance_m": round(float(cam[i, 2]), 3),
                              "pixel": [int(u[i]), int(v[i])], "pose": _pose_xy_yaw(poses[i])})
            if len(found) >= SEEN_MAX:
                break
        return {"x": x, "y": y, "z": round(z, 3), "candidates": int(inside.sum()), "frames": found}

    def ego_png(self, index: int, pixel: tuple[int, int] | None = None) -> bytes:
        frames = self.frames
        if frames is None or not 0 <= index < frames.n_frames:
            raise InputDataError(f"frame {index} is not in {self.name}'s frames.zarr",
                                 field="frame", expected=f"0 .. {0 if frames is None else frames.n_frames - 1}")
        rgb = np.ascontiguousarray(frames.group["rgb"][index])
        if pixel is not None:
            r = max(3, rgb.shape[1] // 40)
            cv2.circle(rgb, pixel, r, (255, 0, 0), max(1, r // 3), cv2.LINE_AA)
        return _png(rgb)

    # ------------------------------------------------------------------------- map-assisted proposals

    def propose(self, which: str, text: str, floor: int = 0) -> dict:
        """The map query's candidates for ``text`` on floor ``floor`` as proposed footprints (outline of each
        connected winning region, world metres) with their scores, and the heatmap as a PNG data URL."""
        import base64

        check_floor(self.recon, self.name, floor)
        view = self.scene.map(which)
        result = view.floor(floor).query(text) if len(self.recon.floors) > 1 else view.query(text)
        grid = result.grid
        r0, r1, c0, c1 = self._get("observed_rc", self._observed_rc)  # the heatmap is sent for the observed box
        heat = result.heatmap[r0:r1, c0:c1]
        rgba = np.zeros((*heat.shape, 4), np.uint8)
        rgba[..., :3] = cv2.applyColorMap((np.clip(np.nan_to_num(heat), 0, 1) * 255).astype(np.uint8),
                                          cv2.COLORMAP_INFERNO)[..., ::-1]
        rgba[..., 3] = np.where(np.isfinite(heat), 30 + 190 * np.clip(np.nan_to_num(heat), 0, 1), 0).astype(np.uint8)
        x0, y1 = grid.origin_xy
        cell = grid.cell_size_m
        proposals = []
        for c in result.candidates:
            b0, b1, b2, b3 = c.bbox_rc
            mask = (result.labels[b0:b2, b1:b3] == c.label).astype(np.uint8)
            outline = _outline(mask, grid, offset_rc=(b0, b1))
            if len(outline) >= 3:
                proposals.append({"rank": c.obj_id, "score": round(float(c.score), 3),
                                  "area_m2": round(float(c.area_m2), 3), "center_xy": [float(v) for v in c.center_xy],
                                  "footprint": outline})
        return {"text": text, "map": which, "floor": floor, "seconds": round(result.seconds, 3), "proposals": proposals,
                "heatmap": "data:image/png;base64," + base64.b64encode(_png(rgba)).decode(),
                "heatmap_extent_xy": [x0 + c0 * cell, x0 + c1 * cell, y1 - r1 * cell, y1 - r0 * cell]}

    # ------------------------------------------------------------------------- procedural preview

    def route(self, start: tuple[float, float, float] | None, object_keys: list[str], floor: int | None = None
              ) -> dict:
        """The route (polyline, metres) and its procedural text from ``start`` = (x, y, yaw radians) on floor
        ``floor`` (default 0), or from the recording's start pose when None, into the goal region of the objects
        ``object_keys`` of the built goals: :func:`pipeline.nav.region.route_to_goal`, the route the goals stage's
        procedural feedback says (the stored region of the goal with exactly these objects, else the region
        computed as the goals stage computes it); on a building, over the stairs (:mod:`zipon.annotate.floors`).
        ``legs`` [{floor, path}] cut the path per floor."""
        from pipeline.nav.actions import RoutePlanner, RouteSettings
        from pipeline.nav.region import GoalTargets, route_to_goal

        recon = self.recon
        if floor is not None:
            check_floor(recon, self.name, floor)
        goals = self.goals
        if goals is None:
            raise InputDataError(f"scene {self.name} has no goals.zarr", field="goals")
        unknown = [k for k in object_keys if k not in goals.objects]
        if unknown or not object_keys:
            raise InputDataError(f"unknown objects {unknown}" if unknown else "no objects given", field="objects",
                                 expected="object keys of the scene")
        if start is None:
            if goals.attrs.get("start_pose") is None:
                raise InputDataError(f"scene {self.name} has no recorded start pose", field="start",
                                     expected="x and y of a start on the map")
            start = tuple(float(v) for v in goals.attrs["start_pose"])
            floor = recorded_start_floor(recon, self.frames)
        floor = floor or 0
        grid = recon.floor(floor).grid
        if not grid.inside(grid.world_to_cell(np.array(start[:2]))):
            raise InputDataError(f"start ({start[0]:g}, {start[1]:g}) is off the map", field="start")
        if len(recon.floors) > 1:
            return building_route(self, start, floor, tuple(object_keys))
        task = self.scene.params.task
        planner = self._get("planner", lambda: RoutePlanner(recon.navigable, grid, RouteSettings.from_config(task)))
        members = tuple(object_keys)
        targets = self._get(("targets", members), lambda: GoalTargets.of(
            self._goal_region(members), goals.footprint_mask(list(members)), grid, stop_radius_m=task.stop_radius_m))
        centres = np.array([goals.objects[k].mass_center for k in members], np.float64).reshape(-1, 2)
        route = route_to_goal(planner, start, targets, key=("preview", members), face_xy=centres)
        head = {"start": [float(v) for v in start], "start_floor": 0, "goal_floor": 0, "stairs": []}
        if route is None:
            return {"reachable": False, "path": [], "legs": [], "text": None, **head}
        path = _rounded(route.path.polyline_xy)
        return {"reachable": True, "path": path, "legs": [{"floor": 0, "path": path}],
                "text": route.text if route.parts else "", "length_m": round(float(route.path.length_m), 2), **head}

    def _goal_region(self, members: tuple[str, ...]) -> np.ndarray:
        """The goal region of ``members``: the stored one of the built goal with exactly these objects, else
        computed as the goals stage computes it (:class:`pipeline.goals.build.GoalRegions`)."""
        goals = self.goals
        for g in goals.goals:
            if sorted(g.object_keys) == sorted(members):
                return goals.goal_region(g.id)
        from pipeline.goals.build import GoalRegions

        floor = goals.objects[members[0]].floor
        return GoalRegions(self.recon, goals.object_set(), goals.success_m, floor)(
            members, goals.object_index(floor), goals.object_keys)


# ----------------------------------------------------------------------------- helpers

def _object_json(o) -> dict:
    return {"key": o.key, "cls": o.cls, "room": o.room, "floor": o.floor, "footprint": [list(map(float, p)) for p in o.footprint],
            "mass_center": [float(v) for v in o.mass_center], "color_name": o.color_name, "material": o.material,
            "size": o.size, "instance_id": o.instance_id, "z_range": [float(v) for v in o.z_range],
            "description": list(o.description)}


def _pose_xy_yaw(T: np.ndarray) -> list[float]:
    return [round(float(T[0, 3]), 3), round(float(T[1, 3]), 3), round(math.atan2(T[1, 2], T[0, 2]), 3)]


_rounded = rounded


def _outline(mask: np.ndarray, grid, up: int = 4, offset_rc: tuple[int, int] = (0, 0)) -> list[list[float]]:
    """The outer contour of the largest blob of ``mask`` (whose cell (0, 0) is the grid's ``offset_rc``) as a
    counter-clockwise world polygon along the cells' edges (traced on the mask upsampled ``up`` times, simplified to
    a quarter cell)."""
    big = cv2.resize(np.pad(mask, 1), None, fx=up, fy=up, interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return []
    c = cv2.approxPolyDP(max(contours, key=cv2.contourArea), 1.0, True).reshape(-1, 2).astype(np.float64)
    c = (c + 0.5) / up - 1 + np.array([offset_rc[1], offset_rc[0]])  # (col, row) on the grid, at the cells' edges
    x0, y1 = grid.origin_xy
    xy = np.stack([x0 + c[:, 0] * grid.cell_size_m, y1 - c[:, 1] * grid.cell_size_m], -1)
    if len(xy) >= 3:
        area = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
        if area < 0:
            xy = xy[::-1]
    return _rounded(xy)


def _png(img: np.ndarray) -> bytes:
    if img.ndim == 3 and img.shape[2] == 4:
        bgr = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA)
    elif img.ndim == 3:
        bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    else:
        bgr = img
    ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])  # speed over size: served locally
    return buf.tobytes()


def descriptive_warnings(doc, goals) -> list[dict]:
    """Descriptive feedback that names a colour or material the goal's object does not have."""
    colours = {o.color_name.lower() for o in goals.objects.values() if o.color_name}
    materials = {o.material.lower() for o in goals.objects.values() if o.material}
    found = []
    for i, g in enumerate(doc.goals):
        obj = goals.objects.get(g.objects[0])
        text = g.feedback.descriptive.lower()
        if obj is None or not text:
            continue
        for kind, words, has in (("colour", colours, obj.color_name.lower()), ("material", materials,
                                                                                obj.material.lower())):
            said = sorted(w for w in words if re.search(rf"\b{re.escape(w)}\b", text))
            if has and said and not re.search(rf"\b{re.escape(has)}\b", text):
                found.append({"field": f"goals[{i}].feedback.descriptive",
                              "message": f"says {', '.join(said)} but {obj.key}'s {kind} is {has}"})
    return found
