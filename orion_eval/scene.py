"""Everything one scene's episodes share, built once per scene (per worker process) and cached.

:class:`SceneContext` holds the artifacts, the planner, the world, the success rule, the ego-view
renderer and the detection encoder (both built on first use), and pose-independent caches: map
query results per (map, text), ego views per pose, detections per (pose, text). Agents are
deterministic, so episodes that share a prefix (the same start in several feedback settings)
reuse the work.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
import torch

from orion_eval.artifacts import Artifacts
from orion_eval.nav import NavPlanner
from orion_eval.world import SuccessRule, World
from pipeline.routes.actions import RouteSettings


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


class SceneContext:
    """Per-scene state shared by all episodes (see the module docstring)."""

    def __init__(self, arts: Artifacts):
        self.arts, self.params = arts, arts.params
        ep, rp = self.params.eval, self.params.routes
        self.grid = arts.grid
        self.navigable = arts.navigable
        self.step_m, self.turn_deg = rp.step_m, rp.turn_deg
        self.world = World(self.navigable, self.grid, step_m=rp.step_m, turn_deg=rp.turn_deg)
        self.planner = NavPlanner(self.navigable, self.grid,
                                  RouteSettings(rp.step_m, rp.turn_deg, ep.clearance_m, ep.stop_radius_m))
        # the user's procedural feedback uses the routes stage's own settings
        self.user_planner = NavPlanner(self.navigable, self.grid,
                                       RouteSettings(rp.step_m, rp.turn_deg, rp.clearance_m, rp.stop_radius_m))
        self.success = SuccessRule(self.grid, arts.height, arts.camera_height_m, rule=ep.success_rule,
                                   distance_m=ep.success_distance_m, hfov_deg=ep.hfov_deg, sight=self.sight)
        # viewpoints are explicit target cells: a zero stop radius keeps the region to those cells
        self.view_planner = NavPlanner(self.navigable, self.grid,
                                       RouteSettings(rp.step_m, rp.turn_deg, ep.clearance_m, 0.0))
        self._map_cache: dict[tuple[str, str], list[MapObject]] = {}
        self._view_cache: dict[tuple, object] = {}
        self._det_cache: dict[tuple, list[Detection]] = {}
        self._text_cache: dict[str, torch.Tensor] = {}

    # ------------------------------------------------------------------ goals
    @cached_property
    def object_index(self) -> np.ndarray:
        return self.arts.goals.object_index()

    def footprint_mask(self, keys) -> np.ndarray:
        """``(rows, cols)`` bool footprint of goal objects (cached per key tuple)."""
        keys = tuple(keys)
        cache = self.__dict__.setdefault("_fp_cache", {})
        if keys not in cache:
            order = self.arts.goals.object_keys
            cache[keys] = np.isin(self.object_index, [order.index(k) + 1 for k in keys])
        return cache[keys]

    # ------------------------------------------------------------------ sight and viewpoints
    def sight(self, origins_xy, target_xy, z_levels, own, *, every: bool = False) -> np.ndarray:
        """``(N,)`` bool: the target column is in sight from each origin at one (``every``: each) of
        ``z_levels`` (metres above the floor)."""
        from orion_eval.egoview import sight_lines

        out = np.full(len(origins_xy), every)
        for z in z_levels:
            xyz = (float(target_xy[0]), float(target_xy[1]), self.arts.recon.floor_z + float(z))
            seen = sight_lines(self.renderer, origins_xy, xyz, own, self.grid)
            out = (out & seen) if every else (out | seen)
        return out

    def viewpoints(self, key, object_mask: np.ndarray, center_xy, z_levels=(0.3, 0.6)) -> np.ndarray:
        """Full-grid mask of plannable cells within ``eval.stop_radius_m`` of ``object_mask`` from which the object's
        centre column is in sight at every one of ``z_levels``; when none sees it, such cells up to 0.1 m inside the success distance; else
        every cell within the stop radius. Cells 3 cells deep inside the seeing region are preferred. Cached
        per ``key``."""
        cache = self.__dict__.setdefault("_viewpoints", {})
        if key not in cache:
            from pipeline.routes.fmm import target_region
            from scipy import ndimage

            p = self.planner
            own = ndimage.binary_dilation(np.asarray(object_mask, bool), iterations=2)
            full = np.zeros((self.grid.rows, self.grid.cols), bool)
            ep = self.params.eval
            # the stop radius first; when nothing there sees the object, up to just inside the success distance
            for k, radius in enumerate((ep.stop_radius_m, max(ep.stop_radius_m, ep.success_distance_m - 0.1))):
                region = target_region(p.planner.plan_mask, p.crop(object_mask), p.crop_grid, radius)
                rr, cc = np.nonzero(region)
                ok = self.sight(p.crop_grid.cell_to_world(np.stack([rr, cc], axis=1)), center_xy, z_levels, own,
                                every=True) if len(rr) else np.zeros(0, bool)
                if k == 0:
                    fallback = (rr, cc)
                if ok.any():
                    full[rr[ok] + p.window[0].start, cc[ok] + p.window[1].start] = True
                    # prefer cells deep inside the seeing region: the walk ends within half a step of its goal
                    core = ndimage.binary_erosion(full, iterations=3)
                    full = core if core.any() else full
                    break
            else:
                rr, cc = fallback
                full[rr + p.window[0].start, cc + p.window[1].start] = True
            cache[key] = full
        return cache[key]

    # ------------------------------------------------------------------ maps
    def map_objects(self, which: str, text: str) -> list[MapObject]:
        """Candidates of ``text`` on map ``which`` ('vlmap' | 'cfmap'), pose-independent (cached)."""
        key = (which, text)
        if key not in self._map_cache:
            res = self.arts.map_query(which).query(text, None)
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
        return EgoRenderer(self.arts.recon.mesh_path, floor_z=self.arts.recon.floor_z,
                           camera_height_m=self.arts.camera_height_m, size=tuple(ep.detect_size),
                           hfov_deg=ep.hfov_deg, gt=self.arts.gt)

    @cached_property
    def encoder(self):
        """The detection encoder: ``eval.detect_encoder`` or the VLMap's; the oracle renders at detect_size."""
        from pipeline.encoders import build_encoder

        ep, enc = self.params.eval, self.params.encoders
        name = ep.detect_encoder
        if name in (None, "vlmap", "cfmap"):
            name = self.arts.map_query(name or "vlmap").map.encoder["name"]
        if name == "oracle":
            enc = enc.model_copy(update={"oracle": enc.oracle.model_copy(update={"out_size": tuple(ep.detect_size)})})
        e = build_encoder(enc, name)
        e.bind_scene(self.arts.gt)
        return e

    def text_features(self, texts: list[str]) -> torch.Tensor:
        missing = [t for t in dict.fromkeys(texts) if t not in self._text_cache]
        if missing:
            for t, f in zip(missing, self.encoder.encode_text(missing).float()):
                self._text_cache[t] = f
        return torch.stack([self._text_cache[t] for t in texts])

    def pose_key(self, pose) -> tuple[int, int, int]:
        x, y, yaw = pose
        return (round(x / 0.05), round(y / 0.05), round(yaw / math.radians(self.turn_deg)))

    def view(self, pose):
        k = self.pose_key(pose)
        if k not in self._view_cache:
            self._view_cache[k] = self.renderer.render(pose)
        return self._view_cache[k]

    def detect(self, pose, text: str) -> list[Detection]:
        """Objects matching ``text`` in the ego view at ``pose`` (cached per pose and text)."""
        key = (self.pose_key(pose), text)
        if key in self._det_cache:
            return self._det_cache[key]
        ep, mp = self.params.eval, self.params.maps
        v = self.view(pose)
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
        g = self.grid
        for k in range(1, n):
            m = lab == k
            npx = int(m.sum())
            score = float(prob[m].mean())
            if npx < ep.detect_min_pixels or score < mp.min_candidate_score:
                continue
            xy = pts[m][:, :2].astype(np.float64)
            rc = g.world_to_cell(xy)
            rc = rc[g.inside(rc)]
            cells = np.unique(rc[:, 0] * g.cols + rc[:, 1])
            out.append(Detection(np.median(xy, axis=0), cells, score, npx))
        out.sort(key=lambda d: -d.pixels)
        self._det_cache[key] = out
        return out
