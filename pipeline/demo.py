"""Pictures for ``zipon demo``: one picture per artifact that exists, under DATA/artifacts/<scene>/renders/."""

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

                written.append(render_scene_png(scene.gt, out / "plan.png"))
        if art["recon"].exists():
            from pipeline.recon.render import render_recon

            for what in ("navigable", "color"):
                written.append(render_recon(art["recon"], what, out / f"{what}.png"))
        if art["goals"].exists() and art["recon"].exists():
            from pipeline.goals.render import render_goals

            written.append(render_goals(art["recon"], art["goals"], None, "goals", out / "goals.png"))
            if art["routes"].exists():
                written.append(render_goals(art["recon"], art["goals"], art["routes"], "routes", out / "routes.png"))
        for which in ("vlmap", "cfmap"):
            if art[which].exists() and art["goals"].exists():
                written.append(_query_picture(scene, which, out))
    return written


def _query_picture(scene: Scene, which: str, out: Path) -> Path:
    """Query the map for the class of the scene's first goal, from the recording's start pose."""
    from pipeline.maps.query import query_map
    from pipeline.maps.render import render_query

    goals = scene.goals
    first = goals.document.goals[0]
    cls = goals.objects[first.objects[0]].cls
    start = goals.meta.start_pose
    result = query_map(scene.path(which), scene.path("recon"), cls, tuple(start) if start else None,
                       params=scene.params, frames_path=scene.path("frames"))
    return render_query(result, out / f"query_{which}_{cls}.png")
