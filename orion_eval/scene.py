"""Everything one scene's episodes share, built once per scene (per worker process) and cached.

:class:`SceneContext` holds the artifacts, the planner, the world, the success rule, the ego-view
renderer and the detection encoder (both built on first use), route targets (the routes module's goal
region: stored in goals.zarr for ground-truth goals, computed with the same function for found objects), and
pose-independent caches: map
query results per (map, text, floor), ego views per pose, detections per (pose, text). Agents are
deterministic, so episodes that share a prefix (the same start in several feedback settings)
reuse the work.

A building is evaluated floor by floor: one :class:`Level` per floor (its navigable and height grids, its camera
height, its planners and success rule), the world's floors joined at the stairs the reconstruction found
(:class:`~orion_eval.world.Stairway`, their ends the building planner's), each floor's ego views rendered from its
own camera height, and the building planner (:attr:`SceneContext.building`) for the user's directions across floors.
A single-floor scene has one level, built exactly as before buildings (its attributes ``planner``, ``world``,
``success``... are floor 0's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
import torch

from orion_eval.nav import NavPlanner
from orion_eval.world import SuccessRule, World
from pipeline.encoders.base import cached_text_features
from pipeline.nav.actions import RouteSettings
from pipeline.scene import Scene


@dataclass
class MapObject:
    """A pose-independent map candidate: centre (world), its cells (flat ids), score and area."""

    center_xy: np.ndarray
    cells: np.ndarray  # flat cell ids of the component
    cells_xy: np.ndarray  # (K,2) world centres of the cells (a subsample for distances)
    score: float
    area_m2: float


@dataclass
class Detection:
    """An object seen in an ego view: world position, flat grid cells of its hits, score, pixel count."""

    center_xy: np.ndarray
    cells: np.ndarray
    score: float
    pixels: int


@dataclass
class Level:
    """One floor as the agents and the user see it: its full-grid ``navigable`` and ``height`` grids, the camera
    height above it, its planners (the agents', the goal-region one, the user's), its success rule and its line of
    sight. A single-floor scene has one, floor 0, built exactly as before buildings."""

    floor: int
    navigable: np.ndarray
    height: np.ndarray
    camera_height_m: float
    planner: NavPlanner
    view_planner: NavPlanner
    user_planner: NavPlanner
    success: SuccessRule | None = None


class SceneContext:
    """Per-scene state shared by all episodes (see the module docstring)."""

    def __init__(self, scene: Scene):
        self.scene, self.params = scene, scene.params
        ep, task = self.params.eval, self.params.task
        self.grid = scene.grid
        self.floor_ids = list(range(len(scene.recon.floors)))
        self.is_building = len(self.floor_ids) > 1
        # the action space and success radius routes.zarr was built with (Scene checks the params agree)
        self.step_m, self.turn_deg, self.success_m = scene.action_space()
        space = {"step_m": self.step_m, "turn_deg": self.turn_deg}
        # the agents' goto_object stops within their own radius of a found object; the agents' planners get an agent
        # stranded off the clearance band back into it (orion_eval.nav)
        agent_settings = RouteSettings.from_config(task, **space, stop_radius_m=ep.goto_stop_radius_m)
        # the user's procedural feedback is planned as the routes stage plans, into the stored goal region; route
        # targets (pipeline.nav.region) are explicit cells: a zero stop radius keeps them as they are
        self.user_settings = RouteSettings.from_config(task, **space, stop_radius_m=0.0)
        self.levels: list[Level] = []
        for f in self.floor_ids:
            nav = scene.navigable if not self.is_building else scene.recon.floor(f).navigable
            height = scene.height if not self.is_building else scene.recon.floor(f).height
            self.levels.append(Level(
                f, nav, height, self.camera_height(f),
                planner=NavPlanner(nav, self.grid, agent_settings, recover=True),
                view_planner=NavPlanner(nav, self.grid, self.user_settings, recover=True),
                user_planner=NavPlanner(nav, self.grid, self.user_settings)))
            self.levels[f].success = SuccessRule(self.grid, height, self.levels[f].camera_height_m,
                                                 rule=ep.success_rule, distance_m=self.success_m,
                                                 hfov_deg=task.hfov_deg, sight=self.sight_on(f))
        ground = self.levels[0]
        self.navigable, self.planner, self.view_planner = ground.navigable, ground.planner, ground.view_planner
        self.user_planner, self.success = ground.user_planner, ground.success
        # the world tests a step in the planners' frame (their cropped grid; all three crop alike), so a step a
        # planner judged free is free: a segment is sampled by its length in cells, and the same step measured
        # in full-grid coordinates (5.0000000001 cells) can get one sample more, which can land in a wall cell
        self.world = World(self.planner.crop(self.navigable), self.planner.crop_grid, step_m=self.step_m,
                           turn_deg=self.turn_deg,
                           floors={lv.floor: (lv.planner.crop(lv.navigable), lv.planner.crop_grid)
                                   for lv in self.levels[1:]},
                           stairs=self.stairways())
        self._map_cache: dict[tuple[str, str, int], list[MapObject]] = {}
        self._view_cache: dict[tuple, object] = {}
        self._det_cache: dict[tuple, list[Detection]] = {}
        self._text_cache: dict[str, torch.Tensor] = {}

    # ------------------------------------------------------------------ floors
    def level(self, floor: int) -> Level:
        return self.levels[floor]

    def camera_height(self, floor: int) -> float:
        """The ego camera's height above ``floor``: the scene's (``eval.camera_height_m`` or the recording's median)
        on a single floor; in a building, the median over the frames taken on that floor (as the goals stage sights
        each floor's goal regions: :class:`pipeline.goals.build.GoalRegions`)."""
        if not self.is_building or self.params.eval.camera_height_m is not None:
            return self.scene.camera_height_m
        from pipeline.nav.region import recorded_camera_height

        recon = self.scene.recon
        poses = recon.poses
        on = recon.floor_of_z(poses[:, 2, 3]) == floor
        return recorded_camera_height(poses[on] if on.any() else poses, recon.floor(floor).floor_z)

    @cached_property
    def building(self):
        """The :class:`~pipeline.nav.building.BuildingPlanner` over the floors (the user's settings), None on a
        single floor: the user's directions across floors and the stairs' ends."""
        if not self.is_building:
            return None
        from pipeline.nav.building import building_planner

        return building_planner(self.scene.recon, self.user_settings)

    def stairways(self) -> list:
        """The building's stairs as the world walks them (:class:`~orion_eval.world.Stairway`): stepped onto from the
        cells routes lead to (:meth:`~pipeline.nav.building.BuildingPlanner.stair_end_cells`) and from the end itself,
        where a climb from the other floor arrives; none on one floor."""
        if self.building is None:
            return []
        from orion_eval.world import Stairway

        out = []
        for lk in self.building.links:
            ends = {f: self.building.stair_end_cells(lk, f) for f in (lk.lower, lk.upper)}
            if any(e is None for e in ends.values()):
                continue
            for f, mask in ends.items():  # and the end itself, where a climb arrives (it may lie off the band)
                mask = ends[f] = mask.copy()
                rc = self.grid.world_to_cell(np.asarray(lk.end_on(f), np.float64))
                if self.grid.inside(rc):
                    mask[rc[0], rc[1]] = True
            out.append(Stairway(lk, ends, self.grid, self.step_m))
        return out

    def episode_floor(self, episode_id: str) -> int:
        """The floor routes.zarr's episode ``episode_id`` starts on (0 on a single floor or for an unknown id)."""
        if not self.is_building:
            return 0
        floors = self.__dict__.setdefault("_episode_floors", {})
        if not floors:
            floors.update({e.id: int(e.start_floor) for e in self.scene.routes.episodes})
        return floors.get(episode_id, 0)

    def room_at(self, pose) -> str | None:
        """The room id at ``pose`` on its floor (simulated scenes), else None."""
        from orion_eval.world import floor_of

        if not self.is_building:
            return self.scene.room_at(pose[:2])
        floor = floor_of(pose)
        rooms = [r for r in (self.scene.gt.rooms if self.scene.gt is not None else []) if (r.floor or 0) == floor]
        p = np.asarray(pose[:2], np.float64)
        for room in rooms:
            if cv2.pointPolygonTest(np.asarray(room.polygon, np.float32).reshape(-1, 1, 2),
                                    (float(p[0]), float(p[1])), False) >= 0:
                return room.id
        return None

    # ------------------------------------------------------------------ goals
    @cached_property
    def object_index(self) -> np.ndarray:
        return self.scene.goals.object_index()

    def floor_object_index(self, floor: int) -> np.ndarray:
        """``(rows, cols)`` int32 footprints of ``floor``'s objects (1 + index into the goals' object keys)."""
        if floor == 0:
            return self.object_index
        cache = self.__dict__.setdefault("_floor_index", {})
        if floor not in cache:
            cache[floor] = self.scene.goals.object_index(floor)
        return cache[floor]

    def footprint_mask(self, keys) -> np.ndarray:
        """``(rows, cols)`` bool footprint of goal objects, on their floor's grid (cached per key tuple)."""
        keys = tuple(keys)
        cache = self.__dict__.setdefault("_fp_cache", {})
        if keys not in cache:
            goals = self.scene.goals
            order = goals.object_keys
            floor = goals.objects[keys[0]].floor if keys else 0
            cache[keys] = np.isin(self.floor_object_index(floor), [order.index(k) + 1 for k in keys])
        return cache[keys]

    # ------------------------------------------------------------------ sight and goal regions
    @cached_property
    def mesh_sight(self):
        """The routes module's line-of-sight test (:class:`pipeline.nav.region.MeshSight`) on the recon mesh."""
        return self.renderer.sight(self.grid)

    def sight(self, origins_xy, target_xy, z_levels, own, *, every: bool = False) -> np.ndarray:
        """``(N,)`` bool: the target column is in sight from each origin at one (``every``: each) of
        ``z_levels`` (metres above the floor)."""
        return self.mesh_sight(origins_xy, target_xy, z_levels, own, every=every)

    def sight_on(self, floor: int):
        """:meth:`sight` on ``floor`` (its floor height and camera height; floor 0's is :meth:`sight` itself)."""
        if floor == 0:
            return self.sight
        cache = self.__dict__.setdefault("_floor_sights", {})

        def sight(origins_xy, target_xy, z_levels, own, *, every: bool = False) -> np.ndarray:
            if floor not in cache:
                cache[floor] = self.renderer_on(floor).sight(self.grid)
            return cache[floor](origins_xy, target_xy, z_levels, own, every=every)
        return sight

    def goal_target(self, key, object_mask: np.ndarray, center_xy, z_levels, floor: int = 0
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Full-grid ``(region, target)`` for an object the agent found (map candidate, detection) on ``floor``: the
        routes module's :func:`~pipeline.nav.region.goal_region` (routes.zarr's ``success_m``, the same
        line of sight as the success rule) and its :func:`~pipeline.nav.region.route_target`
        (``eval.goto_stop_radius_m``), which a walk aims for and the region it finishes in. Cached per ``key``."""
        cache = self.__dict__.setdefault("_goal_targets", {})
        if (key, floor) not in cache:
            from pipeline.nav.region import goal_region, route_target

            ep = self.params.eval
            region = goal_region(self.levels[floor].navigable, object_mask, self.grid, center_xy, z_levels,
                                 self.sight_on(floor), success_m=self.success_m)
            cache[key, floor] = (region, route_target(region, object_mask, self.grid,
                                                      stop_radius_m=ep.goto_stop_radius_m))
        return cache[key, floor]

    def goal_targets(self, goal):
        """The :class:`~pipeline.nav.region.GoalTargets` of a ground-truth goal's stored region (cached per goal)."""
        from pipeline.nav.region import GoalTargets

        targets = self.__dict__.setdefault("_stored_targets", {})
        if goal.id not in targets:
            targets[goal.id] = GoalTargets.of(self.stored_goal_region(goal), self.footprint_mask(goal.object_keys),
                                              self.grid, stop_radius_m=self.params.task.stop_radius_m)
        return targets[goal.id]

    def route_to_goal(self, planner, pose, goal, *, key, face_xy):
        """Route into a ground-truth goal's stored region, as the routes stage plans it
        (:func:`pipeline.nav.region.route_to_goal`), walked in this scene's world; None when unreachable.
        ``planner`` is one of the goal's floor's planners and ``pose`` on that floor."""
        from pipeline.nav.region import route_to_goal

        return route_to_goal(planner, pose, self.goal_targets(goal), key=(key, goal.id), face_xy=face_xy,
                             walk_end=lambda route: self.walk_end(route, pose))

    def route_across(self, pose, goal, *, key, face_xy):
        """The route from ``pose`` on another floor than ``goal``'s, over the stairs, into the goal's stored region
        (:meth:`pipeline.nav.building.BuildingPlanner.route_to_goal`, as the goals stage plans procedural feedback
        across floors): a :class:`~pipeline.nav.building.FloorRoute`, None when no stairs lead there."""
        from orion_eval.world import floor_of

        return self.building.route_to_goal(floor_of(pose), tuple(float(v) for v in pose), goal.floor,
                                           self.goal_targets(goal), key=(key, goal.id), face_xy=face_xy)

    def walk_end(self, route, pose) -> np.ndarray:
        """``(2,)`` world xy where walking ``route`` from ``pose`` in this scene's world ends."""
        from orion_eval.world import Body, floor_of

        body = Body(*(float(v) for v in pose), floor=floor_of(pose))
        for a in route.actions.tolist():
            if a == 0:
                break
            self.world.act(body, a)
        return np.array([body.x, body.y])

    def stored_goal_region(self, goal) -> np.ndarray:
        """Full-grid goal region of a GROUND-TRUTH goal as stored in goals.zarr (cached per goal)."""
        cache = self.__dict__.setdefault("_stored_regions", {})
        if goal.id not in cache:
            cache[goal.id] = self.scene.goals.goal_region(goal.id)
        return cache[goal.id]

    # ------------------------------------------------------------------ maps
    def map_objects(self, which: str, text: str, floor: int = 0) -> list[MapObject]:
        """Candidates of ``text`` on map ``which`` ('vlmap' | 'cfmap') of ``floor``, pose-independent (cached)."""
        key = (which, text, floor)
        if key not in self._map_cache:
            res = self.scene.map_query(which, floor).query(text, None)
            out = []
            g = self.grid
            r_all, c_all = np.nonzero(res.labels)  # one pass over the grid, then per component
            lab_all = res.labels[r_all, c_all]
            for c in res.candidates:
                sel = lab_all == c.label
                rr, cc = r_all[sel], c_all[sel]
                flat = rr.astype(np.int64) * g.cols + cc
                sub = max(1, len(flat) // 64)
                xy = g.cell_to_world(np.stack([rr[::sub], cc[::sub]], axis=1))
                out.append(MapObject(np.asarray(c.center_xy), flat, xy, c.score, c.area_m2))
            self._map_cache[key] = out
        return self._map_cache[key]

    # ------------------------------------------------------------------ ego views and detection
    @cached_property
    def renderer(self):
        from orion_eval.egoview import EgoRenderer

        ep = self.params.eval
        return EgoRenderer(self.scene.recon.mesh_path, floor_z=self.scene.recon.floor_z,
                           camera_height_m=self.levels[0].camera_height_m, size=tuple(ep.detect_size),
                           hfov_deg=self.params.task.hfov_deg, gt=self.scene.gt)

    def renderer_on(self, floor: int):
        """The ego-view renderer of ``floor`` (the one mesh, the camera above that floor)."""
        if floor == 0:
            return self.renderer
        cache = self.__dict__.setdefault("_floor_renderers", {})
        if floor not in cache:
            cache[floor] = self.renderer.on_floor(self.scene.recon.floor(floor).floor_z,
                                                  self.levels[floor].camera_height_m)
        return cache[floor]

    @cached_property
    def encoder(self):
        """The detection encoder: ``eval.detect_encoder`` or the VLMap's; the oracle renders at detect_size."""
        from pipeline.encoders import build_encoder

        ep, enc = self.params.eval, self.params.encoders
        name = ep.detect_encoder
        if name in (None, "vlmap", "cfmap"):
            name = self.scene.map_query(name or "vlmap").map.encoder["name"]
        if name == "oracle":
            enc = enc.model_copy(update={"oracle": enc.oracle.model_copy(update={"out_size": tuple(ep.detect_size)})})
        e = build_encoder(enc, name, runtime=self.params.run)
        e.bind_scene(self.scene.gt)
        return e

    def text_features(self, texts: list[str]) -> torch.Tensor:
        return cached_text_features(self.encoder, self._text_cache, texts)

    def pose_key(self, pose) -> tuple[int, ...]:
        """The place (5 cm) and heading (turn step) a pose is at, and its floor when not 0: what a spin is
        remembered by, what seeds the detector's and the user's draws. Not what a view is cached by
        (:meth:`view_key`)."""
        from orion_eval.world import floor_of

        x, y, yaw = pose
        key = (round(x / 0.05), round(y / 0.05), round(yaw / math.radians(self.turn_deg)))
        return key + (floor_of(pose),) if floor_of(pose) else key

    def view_key(self, pose) -> tuple[int, int, int]:
        """The pose in micrometres and microradians: the ego view and its detections are cached by it and rendered
        at it (:meth:`view`), so a view is a function of the key alone, whichever pose with that key came first.
        Walks that reach a pose by the same actions reach it to the float, so their views are shared; a coarser
        key would give a pose the view of another pose a few centimetres or degrees away, the one an earlier
        episode in the same process happened to stand at. The floor follows when it is not 0."""
        from orion_eval.world import floor_of

        key = tuple(round(float(v) * 1e6) for v in pose)
        return key + (floor_of(pose),) if floor_of(pose) else key

    @staticmethod
    def view_pose(key: tuple[int, ...]):
        """The pose a :meth:`view_key` names: where its view is rendered and its detections are made."""
        from orion_eval.world import Pose

        return Pose((v * 1e-6 for v in key[:3]), key[3] if len(key) > 3 else 0)

    def view(self, pose):
        from orion_eval.world import floor_of

        k = self.view_key(pose)
        if k not in self._view_cache:
            pose = self.view_pose(k)
            self._view_cache[k] = self.renderer_on(floor_of(pose)).render(pose)
        return self._view_cache[k]

    @cached_property
    def detector(self):
        """The simulated open-vocabulary detector (:mod:`orion_eval.detector`) when the maps come from simulated
        perception (the detection encoder has its CLIP text space) on a simulated scene; None otherwise: the
        oracle diagnostic and real encoders detect with the encoder's own features (:meth:`detect`)."""
        return self._simulated_detector("grounded")

    @cached_property
    def saliency_detector(self):
        """CoW's simulated CLIP-saliency localiser (:class:`orion_eval.detector.SaliencyDetector`), where
        :attr:`detector` exists; None otherwise."""
        return self._simulated_detector("saliency")

    def object_phrase(self, text: str) -> str | None:
        """The object a phrase names, without the colour and material it says ("the beige sink made of metal": "sink"),
        as the detection's text model parses a prompt (:meth:`pipeline.encoders.perception_text.ClipTextSpace.parse`);
        None when the phrase says no colour or material (nothing to check it by) or detection has no such parser."""
        space = getattr(self.encoder, "space", None)
        if space is None:
            return None
        q = space.parse(text)
        return " ".join(q.class_names) if q.class_names and (q.colors or q.materials) else None

    def _simulated_detector(self, kind: str):
        space = getattr(self.encoder, "space", None)
        if space is None or self.scene.gt is None or self.renderer.boxes is None:
            return None
        from orion_eval.detector import SaliencyDetector, SimulatedDetector

        cls = SaliencyDetector if kind == "saliency" else SimulatedDetector
        return cls(self.params.eval.detector, space, self.scene.gt, self.renderer.boxes)

    def _detection(self, xy: np.ndarray, score: float, pixels: int) -> Detection:
        """A detection from the world ``(N,2)`` points of its pixels."""
        g = self.grid
        rc = g.world_to_cell(xy)
        rc = rc[g.inside(rc)]
        return Detection(np.median(xy, axis=0), np.unique(rc[:, 0] * g.cols + rc[:, 1]), score, pixels)

    def detect(self, pose, text: str, kind: str = "grounded") -> list[Detection]:
        """Objects matching ``text`` in the ego view at ``pose`` (cached per pose, text and kind): the simulated
        detector's sightings (``kind`` 'grounded': :attr:`detector`, 'saliency': :attr:`saliency_detector`), else
        (real encoders, the oracle) the cells whose encoder features beat the background, for either kind."""
        key = (self.view_key(pose), text, kind)
        if key in self._det_cache:
            return self._det_cache[key]
        pose = self.view_pose(key[0])
        ep, mp = self.params.eval, self.params.query
        v = self.view(pose)
        detector = self.saliency_detector if kind == "saliency" else self.detector
        if detector is not None:
            from orion_eval.world import floor_of

            renderer = self.renderer_on(floor_of(pose))
            T = renderer.T_world_camera(pose)
            dirs = renderer.dirs_cam.reshape(-1, 3).astype(np.float64) @ T[:3, :3].T
            found = detector.detect(v, text, T[:3, 3], dirs, ep.detect_max_range_m, key=self.pose_key(pose))
            out = [self._detection(v.points[s.mask][:, :2].astype(np.float64), s.score, int(s.mask.sum()))
                   for s in found]
            out.sort(key=lambda d: -d.pixels)
            self._det_cache[key] = out
            return out
        feats = self.encoder.encode_images(v.rgb[None], depth_m=v.depth_m[None],
                                           instance=None if v.instance is None else v.instance[None])
        f = feats.features[0]  # (h,w,D)
        h, w = f.shape[:2]
        H, W = v.hit.shape
        rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
        cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
        hit = v.hit[rows[:, None], cols[None, :]] & feats.valid[0].numpy()
        pts = v.points[rows[:, None], cols[None, :]]
        depth = v.depth_m[rows[:, None], cols[None, :]]
        q = self.text_features([text, *mp.background])
        s = (f.reshape(-1, f.shape[-1]) @ q.T).numpy().reshape(h, w, -1)
        T = float(mp.temperature or getattr(self.encoder, "temperature", None) or 0.1)
        sq, sb = s[..., 0], s[..., 1:]
        bg_max = sb.max(axis=-1) if sb.shape[-1] else np.full_like(sq, -np.inf)
        lse = np.log(np.exp(sb / T).sum(axis=-1)) if sb.shape[-1] else np.full_like(sq, -np.inf)
        prob = 1.0 / (1.0 + np.exp(np.clip(lse - sq / T, -80, 80)))
        wins = (sq > bg_max) & hit & (depth <= ep.detect_max_range_m)
        n, lab, stats, _ = cv2.connectedComponentsWithStats(wins.astype(np.uint8), connectivity=8)
        out = []
        for k in range(1, n):
            m = lab == k
            npx = int(m.sum())
            score = float(prob[m].mean())
            if npx < ep.detect_min_pixels or score < mp.min_candidate_score:
                continue
            out.append(self._detection(pts[m][:, :2].astype(np.float64), score, npx))
        out.sort(key=lambda d: -d.pixels)
        self._det_cache[key] = out
        return out
