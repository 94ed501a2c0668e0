"""Pictures for ``zipon demo``: one picture per artifact that exists, under DATA/artifacts/<scene>/renders/ (a
building's floor plans, grids, goals and routes: one per floor, ``WHAT_floor<k>.png``; its map queries: every floor
side by side)."""

from __future__ import annotations

from pathlib import Path

from pipeline.pictures import frames_contact_sheet
from pipeline.scene import Scene


def render_all(scenes: list[Scene]) -> list[Path]:
    """Render what each scene has (frames, floor plan, grids, goals, routes, a map query); returns PNG paths."""
    written: list[Path] = []
    for scene in scenes:
        out = scene.workspace.renders(scene.name)
        art = {name: scene.path(name) for name in ("frames", "recon", "vlmap", "cfmap", "goals", "routes")}
        if art["frames"].exists():
            written.append(frames_contact_sheet(art["frames"], out / "frames.png"))
            if scene.gt is not None:
                from pipeline.sim.topdown import render_scene_png

                plans = len(scene.gt.all_floors)
                written += [render_scene_png(scene.gt, out / ("plan.png" if plans == 1 else f"plan_floor{k}.png"),
                                             floor=k) for k in range(plans)]
        if art["recon"].exists():
            from pipeline.recon.render import render_recon

            n_floors = len(scene.floors)
            for what in ("navigable", "color"):
                for k in range(n_floors):
                    name = f"{what}.png" if n_floors == 1 else f"{what}_floor{k}.png"
                    written.append(render_recon(art["recon"], what, out / name, floor=k))
        if art["goals"].exists() and art["recon"].exists():
            from pipeline.goals.render import render_goals

            n_floors = len(scene.floors)
            for k in range(n_floors):
                name = "" if n_floors == 1 else f"_floor{k}"
                written.append(render_goals(art["recon"], art["goals"], None, "goals", out / f"goals{name}.png",
                                            floor=k))
                if art["routes"].exists():
                    written.append(render_goals(art["recon"], art["goals"], art["routes"], "routes",
                                                out / f"routes{name}.png", floor=k))
        for which in ("vlmap", "cfmap"):
            if art[which].exists() and art["goals"].exists():
                written.append(_query_picture(scene, which, out))
    return written


def _query_picture(scene: Scene, which: str, out: Path) -> Path:
    """Query the map for the class of the scene's first goal, from the recording's start pose (on a building: every
    floor, the pose on the floor of the recording's first camera)."""
    from pipeline.maps.query import query_map
    from pipeline.maps.render import render_query

    goals = scene.goals
    first = goals.document.goals[0]
    cls = goals.objects[first.objects[0]].cls
    start = goals.meta.start_pose
    pose = tuple(start) if start else None
    if len(scene.floors) > 1:
        import numpy as np

        cameras = scene.recon.poses[:, 2, 3]
        start_floor = int(scene.recon.floor_of_z(cameras[np.isfinite(cameras)][0]))
        result = scene.map(which).query(cls, pose, pose_floor=start_floor)
    else:
        result = query_map(scene.path(which), scene.path("recon"), cls, pose, params=scene.params,
                           frames_path=scene.path("frames"))
    return render_query(result, out / f"query_{which}_{cls}.png")
