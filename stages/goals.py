"""Stage ``goals``: objects (GT in frames.zarr, a user file, or navchat annotations) -> ``goals.zarr``.

Personalized goals g = (type, name, room, FB) with the four kinds of feedback, on the recon grid.
Landmark line of sight uses the GT walls when the scene is simulated, else recon's occupied cells
outside object footprints; procedural text starts from the recording's first camera pose and
ends in the goal region the routes stage uses (:func:`pipeline.routes.region.group_region`, line of
sight on ``recon_mesh.ply``), planned as the routes stage plans its episodes. A user
edit (``goals.edits[scene]``, written by ``zipon goals import``) replaces the generated document
after it is checked against the scene's objects. Format: :mod:`pipeline.goals.store`.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from pipeline.config import GoalsParams, Params, RoutesParams, StageConfig, section_keys
from pipeline.errors import ConfigError, InputDataError
from pipeline.frames import FrameStore
from pipeline.geometry import GridSpec, camera_yaw
from pipeline.goals.build import GoalSettings, build_goals, prune_document
from pipeline.goals.navchat import check_navchat_coverage, import_navchat, navchat_frame
from pipeline.goals.objects import ObjectSet, objects_from_file, objects_from_gt, rasterize_polygons
from pipeline.goals.schema import document_digest, load_document
from pipeline.goals.store import ARTIFACT, FORMAT_VERSION, write_goals
from pipeline.recon import OCCUPIED, UNKNOWN, Recon
from pipeline.routes.actions import RoutePlanner, RouteSettings
from pipeline.routes.region import MeshSight, group_region, recorded_camera_height
from pipeline.runner import StageContext
from pipeline.scene_gt import GTScene
from pipeline.store import artifact_attrs


def load_objects(scene: str, frames: FrameStore, grid: GridSpec, p, root: Path, log=print):
    """``(ObjectSet, navchat goals document | None, GTScene | None)`` per ``goals.objects``."""
    gt = frames.ground_truth
    kind = p.objects
    if kind == "auto":
        kind = "gt" if gt else "file" if scene in p.objects_files else "navchat" if scene in p.navchat_dirs else ""
    if kind == "gt":
        if not gt:
            raise InputDataError("no ground truth (attrs.ground_truth) to take objects from", path=frames.path,
                                 field="attrs.ground_truth", expected="a simulated scene, or goals.objects: file")
        scene_gt = GTScene.model_validate(gt)
        return objects_from_gt(scene_gt, scene), None, scene_gt
    if kind == "file":
        if scene not in p.objects_files:
            raise ConfigError(f"goals.objects_files.{scene}: no objects file given for scene {scene!r}")
        return objects_from_file(root / p.objects_files[scene], scene), None, None
    if kind == "navchat":
        if scene not in p.navchat_dirs:
            raise ConfigError(f"goals.navchat_dirs.{scene}: no navchat folder given for scene {scene!r}")
        objset, doc = import_navchat(root / p.navchat_dirs[scene], navchat_frame(p.navchat_grid, frames, grid), scene,
                                     log=log)
        return objset, doc, None
    raise ConfigError(f"goals.objects: scene {scene!r} has no ground truth; give goals.objects_files.{scene} "
                      f"or goals.navchat_dirs.{scene}")


def wall_grid(objset: ObjectSet, recon: Recon, gt: GTScene | None, object_index: np.ndarray) -> np.ndarray:
    """Cells that block line of sight: GT walls, else occupied cells away from object footprints."""
    grid = recon.grid
    if gt is not None:
        return gt.occupancy(grid, 0.05, gt.wall_height_m, objects=False)
    near_obj = ndimage.binary_dilation(object_index > 0, iterations=max(1, int(round(0.15 / grid.cell_size_m))))
    return (recon.occupancy == OCCUPIED) & ~near_obj


def region_function(recon: Recon, objset: ObjectSet, success_m: float):
    """``(members, object_index, keys) -> (rows, cols)`` bool goal region, exactly as the routes stage
    computes it (:func:`pipeline.routes.region.group_region`; line of sight by ray casting
    ``recon_mesh.ply`` from the recording's median camera height). The mesh is read on first use."""
    objects = {o.key: o for o in objset.objects}
    state: dict = {}

    def region(members, object_index, keys):
        if "sight" not in state:
            cam_h = recorded_camera_height(recon.poses, recon.floor_z)
            state["sight"] = MeshSight.from_mesh(recon.mesh_path, floor_z=recon.floor_z, camera_height_m=cam_h,
                                                 grid=recon.grid)
        return group_region(recon.navigable, object_index, list(keys), members, objects, recon.grid,
                            state["sight"], success_m=success_m)

    return region


def start_pose(frames: FrameStore) -> tuple[float, float, float] | None:
    poses = frames.poses()
    ok = np.flatnonzero(np.isfinite(poses).all(axis=(1, 2)))
    if not ok.size:
        return None
    T = poses[ok[0]]
    return float(T[0, 3]), float(T[1, 3]), float(camera_yaw(T))


# goals.* entries keyed by scene: a scene's config holds only its own entry
PER_SCENE = ("objects_files", "navchat_dirs", "edits")
# routes.* settings the goals stage plans procedural feedback with (the routes stage's planner and region)
ROUTE_KEYS = ("step_m", "turn_deg", "clearance_m", "stop_radius_m", "success_m")


class Config(StageConfig):
    """The ``goals`` section (of the scene-keyed entries, only this scene's) and the ``routes`` settings that plan
    procedural feedback, so importing goal edits for one scene leaves every other scene up to date."""

    goals: GoalsParams
    routes: RoutesParams

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        own = [f"goals.{k}.{scene}" for k in PER_SCENE if scene in getattr(params.goals, k)]
        return section_keys("goals", GoalsParams, exclude=PER_SCENE) + own + [f"routes.{k}" for k in ROUTE_KEYS]

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "Config":
        g = params.goals
        goals = g.model_copy(update={k: {s: v for s, v in getattr(g, k).items() if s == scene} for k in PER_SCENE})
        defaults = RoutesParams()
        routes = defaults.model_copy(update={k: getattr(params.routes, k) for k in ROUTE_KEYS})
        return cls(goals=goals, routes=routes)

    @classmethod
    def extra_inputs(cls, params: Params, scene: str) -> dict[str, str]:
        g = params.goals
        named = {"objects_file": g.objects_files, "navchat_dir": g.navchat_dirs, "goal_edits": g.edits}
        return {name: paths[scene] for name, paths in named.items() if scene in paths}


def run(ctx: StageContext) -> dict:
    t0 = time.perf_counter()
    p, rp = ctx.config.goals, ctx.config.routes
    frames = FrameStore(ctx.inputs["frames"])
    recon = Recon(ctx.inputs["recon"])
    grid = recon.grid
    objset, navchat_doc, gt = load_objects(ctx.scene, frames, grid, p, ctx.workspace.root, log=ctx.log)
    if objset.source == "navchat":
        check_navchat_coverage(objset, grid, recon.occupancy != UNKNOWN, p.navchat_max_outside,
                               path=p.navchat_dirs[ctx.scene], log=ctx.log)
    edits, edits_path, edits_info = navchat_doc, None, None
    if ctx.scene in p.edits:
        edits_path = ctx.workspace.root / p.edits[ctx.scene]
        edits = load_document(edits_path)
        digest = document_digest(edits)
        if digest not in edits_path.name:
            raise InputDataError(f"content digest {digest} is not in the file name; the file was changed after "
                                 f"import (import it again: zipon goals import)", path=edits_path)
        edits_info = {"path": p.edits[ctx.scene], "digest": digest}
    dropped: list[str] = []
    if edits is not None and p.edits_missing_objects == "drop":
        edits, dropped = prune_document(edits, {o.key for o in objset.objects})
        for d in dropped:
            ctx.log(f"edited goal {d} dropped: its objects no longer exist")
    planner = RoutePlanner(recon.navigable, grid, RouteSettings(rp.step_m, rp.turn_deg, rp.clearance_m,
                                                                rp.stop_radius_m))
    settings = GoalSettings(seed=p.seed, max_goals=p.max_goals, mix=tuple(p.mix),
                            same_goal_radius_m=p.same_goal_radius_m, landmark_radius_m=p.landmark_radius_m,
                            max_landmarks=p.max_landmarks, landmark_min_area_m2=p.landmark_min_area_m2,
                            exclude_classes=tuple(p.exclude_classes))
    object_index = rasterize_polygons([np.asarray(o.footprint) for o in objset.objects], grid)
    walls = wall_grid(objset, recon, gt, object_index)
    pose0 = start_pose(frames)
    res = build_goals(objset, grid, walls, planner=planner, start_pose=pose0, settings=settings, edits=edits,
                      edits_path=edits_path, goal_region=region_function(recon, objset, rp.success_m))
    write_goals(ctx.outputs["goals"], document=res.document, objset=objset, landmarks=res.landmarks,
                object_index=res.object_index, grid=grid,
                attrs=artifact_attrs(ARTIFACT, FORMAT_VERSION, "goals", ctx.params_digest),
                start_pose=pose0, edits=edits_info)
    goals = res.document.goals
    types = {t: sum(g.type == t for g in goals) for t in ("big", "small", "ambiguous")}
    summary = {
        "objects": len(objset.objects), "objects_source": objset.source, "goals": len(goals), **types,
        "same_goal_groups": sum(len(g.objects) > 1 for g in goals),
        "with_landmarks": sum(bool(g.feedback.landmark) for g in goals),
        "with_procedural": sum(g.feedback.procedural is not None for g in goals),
        "edited": bool(res.edited), "dropped_edited_goals": dropped,
        "seconds": round(time.perf_counter() - t0, 3),
    }
    ctx.log(f"{len(goals)} goals ({types['big']} big, {types['small']} small, {types['ambiguous']} ambiguous) "
            f"from {len(objset.objects)} {objset.source} objects")
    return summary
