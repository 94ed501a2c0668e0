"""``zipon view``: one scene as a rerun recording (``.rrd``), opened with ``rerun FILE.rrd``.

Entities (world frame right-handed, z up, metres; see :mod:`pipeline.geometry`)::

    world                         ViewCoordinates RIGHT_HAND_Z_UP (static)
    world/camera                  Transform3D T_world_camera per frame   timelines: frame, capture_time
    world/camera/image            Pinhole (K, OpenCV optical RDF) per frame
    world/camera/image/rgb        EncodedImage (JPEG) per frame
    world/camera/image/depth      EncodedDepthImage (16-bit PNG, millimetres) per frame
    world/trajectory              LineStrips3D: every camera position (static)
    world/mesh                    Mesh3D: the TSDF surface with vertex colours (static)
    world/grids/{color,navigable,height,query}
                                  Mesh3D: top-down grids (and one map query's heatmap) as textured
                                  planes stacked below the floor, cropped to the observed area (static);
                                  a building: world/grids/floor<id>/{...} below each floor, its query
                                  heatmap from that floor's map
    world/goals                   Boxes3D: one box per goal object, labelled with the goal's name, standing on
                                  its floor (static)
    world/routes                  LineStrips3D: every verified episode's geodesic path, each leg on its floor, a
                                  building's climb between them (static)
    world/routes/starts           Arrows3D: start poses (static)
    world/episode/robot           Points3D + Arrows3D: the agent's pose per step          timeline: step
    world/episode/path            LineStrips3D: the path walked so far per step
    world/episode/goal            Boxes3D: the episode's goal (static)
    dialogue                      TextLog: instruction, every Talk turn and the user's reply, per step

Colour frames are JPEG-compressed (``jpeg_quality``), at most ``max_frames`` evenly spaced frames
are logged and the mesh is simplified to ``mesh_voxel_m``; depth is lossless (16-bit PNG), which
dominates the size: a 240-frame 640x480 demo scene writes 21 MB (40 MB with the full mesh).
"""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np

from pipeline.errors import InputDataError, MissingInputError

GRID_LAYERS = ("color", "navigable", "height", "query")
LAYER_GAP_M = 0.25  # grids are stacked this far apart below the floor, so none hides another


def write_recording(ws, params, scene: str, out: str | Path, *, episode: str | None = None,
                    eval_dir: str | Path | None = None, method: str | None = None, feedback: str | None = None,
                    seed: int | None = None, query: str | None = None, max_frames: int = 240,
                    jpeg_quality: int = 85, mesh_voxel_m: float = 0.04, mesh_top_m: float | None = 2.2) -> dict:
    """Write the recording of ``scene`` to ``out`` (written aside, then renamed into place); returns a summary.

    ``episode`` (a routes episode id) replays that episode from the evaluation logs in ``eval_dir``
    (``episodes/<scene>.episodes.jsonl.gz``), the first run matching ``method`` / ``feedback`` /
    ``seed`` when given. ``query`` (default: the class of the scene's first goal) is drawn as a heatmap.
    ``mesh_voxel_m`` > 0 merges mesh vertices within that size (open3d vertex clustering: about a third of the
    bytes at 0.04 m on a TSDF of 0.02 m voxels); 0 logs the full mesh. ``mesh_top_m`` leaves out triangles
    entirely above that height over the floor (the ceiling, which hides the rooms from above); None keeps them.
    """
    import rerun as rr

    from pipeline.store import remove

    out = Path(out)
    if out.suffix != ".rrd":
        raise InputDataError(f"got {out}", field="--out", expected="a FILE.rrd path")
    art = {name: ws.artifact(name, scene) for name in ("frames", "recon", "vlmap", "goals", "routes")}
    if not art["frames"].exists():
        raise MissingInputError(f"{art['frames']}: scene {scene!r} has no frames (build it: zipon run -s {scene})")
    ep_log = None
    if episode is not None:
        ep_log = find_episode(Path(eval_dir) if eval_dir else ws.data_dir / "eval" / "demo", scene, episode,
                              method=method, feedback=feedback, seed=seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    rec = rr.RecordingStream("zipon", recording_id=f"zipon-{scene}")
    rec.save(str(tmp))
    summary: dict = {"scene": scene}
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        summary["frames"], xyz = _log_frames(rec, rr, art["frames"], max_frames, jpeg_quality)
        rec.send_blueprint(_blueprint(ep_log is not None, xyz))
        recon = None
        if art["recon"].exists():
            from pipeline.recon import Recon

            recon = Recon(art["recon"])
            summary["mesh_vertices"] = _log_mesh(rec, rr, recon, mesh_voxel_m, mesh_top_m)
            summary["grids"] = []
            for k, floor in enumerate(recon.floors):
                result = _query(ws, params, scene, art, query, k)
                summary["query"] = None if result is None else result.text
                where = "" if len(recon.floors) == 1 else f"floor{floor.id}/"
                summary["grids"] += [where + what for what in _log_grids(rec, rr, recon, result, k, where)]
        floor_z = recon.floor_z if recon is not None else 0.0
        # each floor's height (a building's goals and route legs stand on their own floor)
        floor_zs = [f.floor_z_m for f in recon.floors] if recon is not None and len(recon.floors) > 1 else [floor_z]
        goals = None
        if art["goals"].exists():
            from pipeline.goals.store import Goals

            goals = Goals(art["goals"])
            summary["goal_boxes"] = _log_goals(rec, rr, "world/goals", goals, goals.goals, floor_zs)
        if art["routes"].exists() and goals is not None:
            from pipeline.routes.store import Routes

            summary["routes"] = _log_routes(rec, rr, Routes(art["routes"]), goals, floor_zs)
        if ep_log is not None:
            if goals is not None:
                _log_goals(rec, rr, "world/episode/goal", goals, [goals.goal(ep_log["goal"])], floor_zs)
            summary.update(_log_episode(rec, rr, ep_log, floor_zs))
        rec.flush()
        rec.disconnect()
        tmp.replace(out)
    finally:
        remove(tmp)
    summary["out"] = str(out)
    summary["bytes"] = out.stat().st_size
    return summary


def _blueprint(with_episode: bool, camera_xyz: np.ndarray):
    """The default layout: the 3D scene (seen from above the walk, south of it) beside the colour and depth
    images, the dialogue when an episode is replayed, and the frame timeline selected."""
    import rerun.blueprint as rrb

    lo, hi = camera_xyz.min(axis=0), camera_xyz.max(axis=0)
    centre = (lo + hi) / 2
    span = float(max(hi[0] - lo[0], hi[1] - lo[1], 2.0)) + 2.0
    eye = rrb.EyeControls3D(position=centre + np.array([0.0, -0.7 * span, 1.1 * span]),
                            look_target=[centre[0], centre[1], lo[2] - 1.0], eye_up=[0.0, 0.0, 1.0])

    side = [rrb.Spatial2DView(origin="/world/camera/image", contents=["/world/camera/image/rgb"], name="colour"),
            rrb.Spatial2DView(origin="/world/camera/image", contents=["/world/camera/image/depth"], name="depth (mm)")]
    if with_episode:
        side.append(rrb.TextLogView(origin="/dialogue", name="dialogue"))
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="/world", name="scene (z up, metres)", eye_controls=eye),
                                        rrb.Vertical(*side), column_shares=[3, 2]),
                         rrb.TimePanel(timeline="frame"), collapse_panels=False)


# ----------------------------------------------------------------------------- frames and geometry

def _log_frames(rec, rr, frames_path: Path, max_frames: int, jpeg_quality: int) -> tuple[int, np.ndarray]:
    """Colour, depth, camera and trajectory; returns the number of frames logged and the ``(N,3)`` camera positions."""
    import cv2

    from pipeline.frames import FrameStore

    fs = FrameStore(frames_path)
    poses = fs.poses()
    stamps = fs.stamps()
    ok = np.isfinite(poses).all(axis=(1, 2))
    keep = np.flatnonzero(ok)
    if len(keep) > max_frames:
        keep = keep[np.unique(np.linspace(0, len(keep) - 1, max_frames).round().astype(int))]
    intr = fs.intrinsics
    rec.log("world/trajectory", rr.LineStrips3D([poses[ok, :3, 3]], colors=[(255, 170, 0)], radii=0.01,
                                                labels=["camera trajectory"]), static=True)
    pinhole = rr.Pinhole(image_from_camera=intr.K, width=intr.width, height=intr.height,
                         camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3)
    for i in keep:
        b = fs.read(int(i), int(i) + 1)
        rec.set_time("frame", sequence=int(i))
        rec.set_time("capture_time", timestamp=np.datetime64(int(stamps[i]), "ns"))
        T = poses[i]
        rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        rec.log("world/camera/image", pinhole)
        good, jpg = cv2.imencode(".jpg", cv2.cvtColor(b.rgb[0], cv2.COLOR_RGB2BGR),
                                 [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        good2, png = cv2.imencode(".png", b.depth_mm[0])
        if not (good and good2):
            raise InputDataError("could not encode the frame for the recording", path=frames_path, frame=int(i))
        rec.log("world/camera/image/rgb", rr.EncodedImage(contents=jpg.tobytes(), media_type="image/jpeg"))
        rec.log("world/camera/image/depth", rr.EncodedDepthImage(png.tobytes(), media_type="image/png", meter=1000.0))
    rec.reset_time()
    return int(len(keep)), poses[ok, :3, 3]


def _log_mesh(rec, rr, recon, voxel_m: float, top_m: float | None) -> int:
    mesh = recon.mesh()
    if top_m is not None and len(mesh.triangles):
        z = np.asarray(mesh.vertices)[:, 2]
        floor_z = np.array([f.floor_z_m for f in recon.floors])[recon.floor_of_z(z)]  # each vertex's floor
        above = (z - floor_z > top_m)[np.asarray(mesh.triangles)].all(axis=1)
        mesh.remove_triangles_by_mask(above)
        mesh.remove_unreferenced_vertices()
    if voxel_m > 0:
        import open3d as o3d

        mesh = mesh.simplify_vertex_clustering(voxel_size=voxel_m,
                                               contraction=o3d.geometry.SimplificationContraction.Average)
        mesh.compute_vertex_normals()
    v = np.asarray(mesh.vertices, np.float32)
    kw = {}
    if mesh.has_vertex_colors():
        kw["vertex_colors"] = (np.asarray(mesh.vertex_colors) * 255).round().astype(np.uint8)
    if mesh.has_vertex_normals():
        kw["vertex_normals"] = np.asarray(mesh.vertex_normals, np.float32)
    rec.log("world/mesh", rr.Mesh3D(vertex_positions=v, triangle_indices=np.asarray(mesh.triangles, np.uint32), **kw),
            static=True)
    return int(len(v))


def _plane(rr, grid, box, z: float, texture: np.ndarray):
    """A textured quad covering cells ``box`` = (r0, r1, c0, c1) of ``grid`` at height ``z``."""
    r0, r1, c0, c1 = box
    s, (x0, y0) = grid.cell_size_m, grid.origin_xy
    xa, xb = x0 + c0 * s, x0 + c1 * s
    ya, yb = y0 - r0 * s, y0 - r1 * s  # north (top row) and south edges
    verts = np.array([[xa, ya, z], [xb, ya, z], [xb, yb, z], [xa, yb, z]], np.float32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)  # texture row 0 = north edge
    return rr.Mesh3D(vertex_positions=verts, triangle_indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                     vertex_texcoords=uv, albedo_texture=texture)


def _log_grids(rec, rr, recon, result, floor: int = 0, where: str = "") -> list[str]:
    """The colour, navigable and height grids and the query heatmap of floor ``floor`` (an index) as textured
    planes below that floor, logged under ``world/grids/<where>``."""
    from pipeline.pictures import colorize
    from pipeline.recon.render import grid_image

    grids = recon.floor(floor)
    g = grids.grid
    seen = np.argwhere(grids.occupancy != 0)
    if not len(seen):
        return []
    (r0, c0), (r1, c1) = seen.min(axis=0), seen.max(axis=0) + 1
    box = (int(r0), int(r1), int(c0), int(c1))
    crop = (slice(box[0], box[1]), slice(box[2], box[3]))
    written = []
    for k, what in enumerate(GRID_LAYERS):
        if what == "query":
            if result is None:
                continue
            heat = result.heatmap[crop]
            tex = np.concatenate([colorize(np.nan_to_num(heat), 0.0, 1.0),
                                  np.where(np.isfinite(heat), 255, 0).astype(np.uint8)[..., None]], axis=-1)
        else:
            img, _ = grid_image(grids, what, recon.robot_radius_m)
            tex = (np.asarray(img)[crop] * 255).round().astype(np.uint8)
        z = grids.floor_z - LAYER_GAP_M * (k + 1)
        rec.log(f"world/grids/{where}{what}", _plane(rr, g, box, z, np.ascontiguousarray(tex)), static=True)
        written.append(what)
    return written


def _query(ws, params, scene: str, art: dict, text: str | None, floor: int = 0):
    """The vlmap query of floor ``floor`` drawn as a heatmap: ``text``, else the class of the first goal; None
    without a map."""
    if not art["vlmap"].exists():
        return None
    if text is None:
        if not art["goals"].exists():
            return None
        from pipeline.goals.store import Goals

        goals = Goals(art["goals"])
        if not goals.goals:
            return None
        text = goals.objects[goals.goals[0].object_keys[0]].cls
    from pipeline.maps.query import open_query

    return open_query(art["vlmap"], params, recon_path=art["recon"], frames_path=art["frames"],
                      floor=floor).query(text)


# ----------------------------------------------------------------------------- goals, routes, episodes

def _goal_colors(n: int) -> np.ndarray:
    from pipeline.pictures import label_colors

    return label_colors(np.arange(1, n + 1)).reshape(-1, 3)


def _log_goals(rec, rr, path: str, goals, views, floor_zs: list[float]) -> int:
    """One labelled box per object of each goal (footprint bounds x height range above its floor, ``floor_zs``
    the world z of each floor); returns the box count."""
    index = {g.id: i for i, g in enumerate(goals.goals)}
    colors = _goal_colors(len(goals.goals))
    centers, half, labels, cols = [], [], [], []
    for gv in views:
        for key in gv.object_keys:
            o = goals.objects[key]
            fp = np.asarray(o.footprint, np.float64)
            lo, hi = fp.min(axis=0), fp.max(axis=0)
            z0, z1 = floor_zs[o.floor] + o.z_range[0], floor_zs[o.floor] + o.z_range[1]
            centers.append([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (z0 + z1) / 2])
            half.append([(hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2, max((z1 - z0) / 2, 0.01)])
            labels.append(f"{gv.name} ({key})")
            cols.append(colors[index[gv.id]])
    if centers:
        rec.log(path, rr.Boxes3D(centers=centers, half_sizes=half, labels=labels, colors=np.asarray(cols, np.uint8),
                                 show_labels=True), static=True)
    return len(centers)


def _log_routes(rec, rr, routes, goals, floor_zs: list[float]) -> int:
    """Every episode's path 5 cm above the floor it is walked on (a building's: leg by leg on each floor, the climb a
    straight segment from one leg's end to the next leg's start) and its start pose."""
    index = {g.id: i for i, g in enumerate(goals.goals)}
    colors = _goal_colors(len(goals.goals))
    eps = routes.episodes
    if not eps:
        return 0
    lift = 0.05
    strips = [np.concatenate([np.column_stack([xy, np.full(len(xy), floor_zs[f] + lift)]) for f, xy in e.legs()])
              for e in eps]
    cols = np.asarray([colors[index.get(e.goal_id, 0)] for e in eps], np.uint8)
    rec.log("world/routes", rr.LineStrips3D(strips, colors=cols, radii=0.02, labels=[e.id for e in eps]), static=True)
    starts = np.asarray([[e.start[0], e.start[1], floor_zs[e.start_floor] + lift] for e in eps])
    yaw = np.asarray([e.start[2] for e in eps])
    rec.log("world/routes/starts", rr.Arrows3D(origins=starts, vectors=np.column_stack(
        [0.4 * np.cos(yaw), 0.4 * np.sin(yaw), np.zeros(len(eps))]), colors=cols), static=True)
    return len(eps)


def find_episode(eval_dir: Path, scene: str, episode: str, *, method=None, feedback=None, seed=None) -> dict:
    """The first evaluated run of route episode ``episode`` matching the filters, from ``eval_dir``'s logs."""
    path = Path(eval_dir) / "episodes" / f"{scene}.episodes.jsonl.gz"
    if not path.is_file():
        raise MissingInputError(f"{path}: no evaluation log of scene {scene!r} (run: zipon eval -s {scene} --out "
                                f"{eval_dir}, or pass --eval DIR)")
    seen = []
    with gzip.open(path, "rt") as f:
        for line in f:
            rec = json.loads(line)
            seen.append(rec["episode"])
            if rec["episode"] == episode and all(v is None or rec[k] == v for k, v in
                                                 (("method", method), ("feedback", feedback), ("seed", seed))):
                return rec
    filters = ", ".join(f"{k} {v!r}" for k, v in (("method", method), ("feedback", feedback), ("seed", seed))
                        if v is not None)
    raise InputDataError(f"no evaluated episode {episode!r}" + (f" with {filters}" if filters else "")
                         + f"; episodes in the log: {sorted(set(seen))}", path=path, field="--episode")


def _log_episode(rec, rr, ep: dict, floor_zs: list[float]) -> dict:
    """Replay an evaluated episode step by step (timeline ``step``) with its dialogue as text logs; in a building
    each pose stands on its floor (the log's ``floors``; ``floor_zs`` the world z of each floor)."""
    log = ep["log"]
    poses = np.asarray(log["poses"], np.float64).reshape(-1, 3)
    on = np.asarray(log.get("floors") or np.zeros(len(poses), int), int)
    if len(on) != len(poses) or on.min() < 0 or on.max() >= len(floor_zs):
        raise InputDataError(f"episode {ep.get('episode')}: {len(on)} floors (ids {sorted(set(on.tolist()))}) for "
                             f"{len(poses)} poses", field="log.floors",
                             expected=f"one floor id of 0..{len(floor_zs) - 1} per pose")
    xyz = np.column_stack([poses[:, :2], np.asarray(floor_zs)[on] + 0.1])
    title = (f"{ep['method']} / {ep['feedback']} / seed {ep['seed']}: episode {ep['episode']} -> goal {ep['goal']} "
             f"({'success' if ep['success'] else 'failure'}, {ep['end']})")
    rec.set_time("step", sequence=0)
    rec.log("dialogue", rr.TextLog(title, level="INFO"))
    rec.log("dialogue", rr.TextLog(f"user: {log['instruction']}", level="INFO"))
    for i, (x, y, yaw) in enumerate(poses):
        rec.set_time("step", sequence=i)
        rec.log("world/episode/robot", rr.Points3D([xyz[i]], radii=0.12, colors=[(230, 40, 200)]),
                rr.Arrows3D(origins=[xyz[i]], vectors=[[0.5 * np.cos(yaw), 0.5 * np.sin(yaw), 0.0]],
                            colors=[(230, 40, 200)]))
        rec.log("world/episode/path", rr.LineStrips3D([xyz[: i + 1]], colors=[(230, 40, 200)], radii=0.03))
    for turn in log["dialogue"]:
        rec.set_time("step", sequence=int(min(turn["step"], len(poses) - 1)))
        level = "INFO" if turn["speaker"] == "agent" else "WARN"
        kind = f" [{turn['kind']}]" if turn.get("kind") else ""
        rec.log("dialogue", rr.TextLog(f"{turn['speaker']}{kind}: {turn['text']}", level=level))
    rec.reset_time()
    return {"episode": ep["episode"], "steps": int(len(poses)), "dialogue": len(log["dialogue"])}


# ----------------------------------------------------------------------------- reading back

def recording_contents(path: str | Path) -> dict[str, dict]:
    """``{entity path: {"rows": n, "static": bool, "components": [...], "timelines": [...]}}`` of an ``.rrd``."""
    import rerun as rr

    path = Path(path)
    if not path.is_file():
        raise MissingInputError(f"{path}: recording not found")
    out: dict[str, dict] = {}
    for chunk in rr.chunk.RrdReader(path).stream():
        e = out.setdefault(chunk.entity_path, {"rows": 0, "static": True, "components": set(), "timelines": set()})
        e["rows"] += chunk.num_rows
        e["static"] &= chunk.is_static
        e["timelines"] |= set(chunk.timeline_names)
        e["components"] |= {n for n in chunk.to_record_batch().schema.names if ":" in n}
    return {k: {**v, "components": sorted(v["components"]), "timelines": sorted(v["timelines"])}
            for k, v in sorted(out.items())}
