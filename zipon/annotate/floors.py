"""The floors of a building as the annotation page shows them: the floor records and stairs the page's floor
selector offers, the check of a floor number a request names, and the route preview across floors.

A single-floor scene is one floor (id 0) and every request that names no floor means it. On a building, a request
that names a floor the scene does not have is refused naming the floors it has. The route preview plans as the goals
stage's procedural feedback does (:mod:`pipeline.goals.floors`, :class:`pipeline.nav.building.BuildingPlanner`): from
the start's floor over the stairs into the goal region on the goal's floor, each floor's last leg with
:func:`pipeline.nav.region.route_to_goal`; from the recording's start it says the stored feedback word for word.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import InputDataError


def floor_records(recon) -> list[dict]:
    """``[{id, name, floor_z_m, ceiling_z_m}]`` of a reconstruction's floors, lowest first (one for one floor)."""
    return [{"id": k, "name": f.name, "floor_z_m": round(float(f.floor_z_m), 3),
             "ceiling_z_m": None if f.ceiling_z_m is None else round(float(f.ceiling_z_m), 3)}
            for k, f in enumerate(recon.floors)]


def stair_records(recon) -> list[dict]:
    """``[{id, kind, bottom {floor, xy}, top {floor, xy}, rise_m}]``: the stairs joining the floors (world metres)."""
    return [{"id": f"stairs_{s.id}", "kind": s.kind, "rise_m": round(float(s.rise_m), 3),
             "bottom": {"floor": int(s.bottom.floor), "xy": [round(float(v), 3) for v in s.bottom.xy]},
             "top": {"floor": int(s.top.floor), "xy": [round(float(v), 3) for v in s.top.xy]}} for s in recon.stairs]


def floors_named(recon) -> str:
    """``"0 (ground floor, 0.00 m), 1 (first floor, 2.86 m)"``: the floors, as a refusal names them."""
    return ", ".join(f"{k} ({f.name}, {f.floor_z_m:.2f} m)" for k, f in enumerate(recon.floors))


def check_floor(recon, scene: str, floor: int) -> int:
    """``floor`` when the scene has it, else an :class:`InputDataError` naming the floors it has."""
    n = len(recon.floors)
    if not 0 <= floor < n:
        raise InputDataError(f"floor {floor}: scene {scene} has {n} floor{'s' if n != 1 else ''}: "
                             f"{floors_named(recon)}", field="floor", expected=f"a floor 0..{n - 1}")
    return floor


def recorded_start_floor(recon, frames) -> int:
    """The floor the recording starts on: that of its first camera with a finite pose (as the goals stage reads
    it, :func:`pipeline.goals.build.scene_building`); 0 for a single floor or no frames."""
    if len(recon.floors) == 1 or frames is None:
        return 0
    poses = frames.poses()
    ok = np.flatnonzero(np.isfinite(poses).all(axis=(1, 2)))
    return int(recon.floor_of_z(poses[ok[0], 2, 3])) if ok.size else 0


def rounded(xy) -> list[list[float]]:
    return [[round(float(a), 3), round(float(b), 3)] for a, b in np.asarray(xy).reshape(-1, 2)]


def building_route(view, start, start_floor: int, members: tuple[str, ...]) -> dict:
    """The route preview on a building (see the module docstring): ``legs`` [{floor, path}] joined by ``stairs``
    [{id, up, from_floor, to_floor, from_xy, to_xy}], its text and length (the stairs along their slope)."""
    from pipeline.nav.actions import RouteSettings
    from pipeline.nav.building import building_planner
    from pipeline.nav.region import GoalTargets

    recon, goals = view.recon, view.goals
    floors = {goals.objects[k].floor for k in members}
    if len(floors) > 1:
        raise InputDataError(f"objects {list(members)} lie on floors {sorted(floors)}; a goal's objects lie on one "
                             "floor", field="objects", expected="object keys of one floor")
    goal_floor = floors.pop()
    task = view.scene.params.task
    building = view._get("building", lambda: building_planner(recon, RouteSettings.from_config(task)))
    grid = building.planners[goal_floor].grid
    targets = view._get(("targets", members), lambda: GoalTargets.of(
        view._goal_region(members), goals.footprint_mask(list(members)), grid,
        stop_radius_m=building.planners[goal_floor].settings.stop_radius_m))
    centres = np.array([goals.objects[k].mass_center for k in members], np.float64).reshape(-1, 2)
    route = building.route_to_goal(start_floor, start, goal_floor, targets, key=("preview", members), face_xy=centres)
    head = {"start": [float(v) for v in start], "start_floor": start_floor, "goal_floor": goal_floor}
    if route is None:
        return {"reachable": False, "path": [], "legs": [], "stairs": [], "text": None, **head}
    legs = [{"floor": f, "path": rounded(leg.path.polyline_xy) if leg is not None else []} for f, leg in route.legs]
    here = start_floor
    stairs = []
    for climb in route.climbs:
        there = climb.link.other(here)
        stairs.append({"id": climb.link.id, "up": climb.up, "from_floor": here, "to_floor": there,
                       "from_xy": rounded(climb.link.end_on(here))[0], "to_xy": rounded(climb.link.end_on(there))[0]})
        here = there
    said = route.parts or route.climbs
    return {"reachable": True, "path": [p for leg in legs for p in leg["path"]], "legs": legs, "stairs": stairs,
            "text": route.text if said else "", "length_m": round(float(route.length_m), 2), **head}


def check_record_floors(recon, scene: str, objset) -> None:
    """Refuse objects or rooms of an edited objects file that lie on a floor the scene does not have, naming them
    and the floors it has."""
    n = len(recon.floors)
    bad = [f"{o.key} (floor {o.floor})" for o in objset.objects if o.floor >= n] + \
        [f"room {r.id} (floor {r.floor})" for r in objset.rooms if r.floor >= n]
    if bad:
        raise InputDataError(f"{', '.join(bad[:5])}: scene {scene} has {n} floor{'s' if n != 1 else ''}: "
                             f"{floors_named(recon)}", field="floor", expected=f"a floor 0..{n - 1}")
