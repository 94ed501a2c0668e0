"""Episodes of a building: each floor's episodes as on a single floor, plus episodes that start on another floor and
take the stairs (:class:`pipeline.nav.building.BuildingPlanner`).

Every goal gets ``episodes_per_goal`` starts on its own floor (:func:`pipeline.routes.episodes.make_episodes` on that
floor's grid) and, for each other floor the stairs join to it, ``cross_floor_per_goal`` starts there: seeded cells
of that floor's clearance mask from which a stair leads on (their geodesic distance through the stairs at least
``min_geodesic_m``). A cross-floor route is verified leg by leg: each leg replayed on its floor's grid without a
collision, each climb starting within :data:`~pipeline.nav.building.STAIR_END_RADIUS_M` of its stair's end, the last
leg ending in the goal region facing the goal. Its reference length ``l`` is the geodesic distance through the stairs
(the floors' fast-marching distances plus each stair's length along its slope).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.config import TaskParams
from pipeline.nav.actions import RouteSettings
from pipeline.nav.building import STAIR_END_RADIUS_M, BuildingPlanner
from pipeline.nav.region import GoalTargets
from pipeline.nav.verify import replay
from pipeline.routes.episodes import Episode, EpisodeSet, GoalTarget, make_episodes


def building_episodes(building: BuildingPlanner, targets: dict[int, list[GoalTarget]], *, episodes_per_goal: int,
                      cross_floor_per_goal: int, min_geodesic_m: float, seed: int, task: TaskParams,
                      progress=lambda it, **kw: it) -> EpisodeSet:
    """Episodes of every goal of ``targets`` ``{floor: [GoalTarget]}`` (regions on that floor's grid): same-floor
    episodes per floor (seed ``(seed, floor)``), then the cross-floor ones (seed ``(seed, floor, goal index)``)."""
    out = EpisodeSet()
    for f in sorted(targets):
        planner = building.planners[f]
        eps = make_episodes(planner.navigable, planner.grid, targets[f], episodes_per_goal=episodes_per_goal,
                            min_geodesic_m=min_geodesic_m, seed=int(np.random.SeedSequence([seed, f]).generate_state(1)[0]),
                            task=task, progress=progress)
        for e in eps.episodes:
            e.start_floor, e.floors, e.segments = f, (f,), (len(e.actions),)
        out.episodes += eps.episodes
        out.rejected += eps.rejected
        out.unreachable += eps.unreachable
    if cross_floor_per_goal <= 0 or len(building.planners) < 2:
        return out
    settings = next(iter(building.planners.values())).settings
    for f in sorted(targets):
        for gi, goal in enumerate(targets[f]):
            if goal.region is None or not goal.region.any():
                continue
            aims = GoalTargets.of(goal.region, goal.object_mask, building.planners[f].grid,
                                  stop_radius_m=settings.stop_radius_m)
            goal_field = building.planners[f].field((goal.id, "region"), goal.region, "navigable", region=True)
            for s in sorted(building.planners):
                if s == f:
                    continue
                rng = np.random.default_rng([seed, f, gi, s])
                for j, start in enumerate(_cross_starts(building, s, f, goal_field, cross_floor_per_goal,
                                                        min_geodesic_m, rng, settings)):
                    eid = f"{goal.id}/floor{s}/{j}"
                    ep, why = _cross_episode(building, eid, goal, aims, s, f, start, goal_field, task, settings)
                    if ep is not None:
                        out.episodes.append(ep)
                    else:
                        out.rejected.append({"episode": eid, "reason": why})
            for planner in building.planners.values():  # the goal's fields on every floor: done with
                planner.forget(goal.id)
    return out


def _cross_starts(building: BuildingPlanner, s: int, f: int, goal_field: np.ndarray, n: int, min_geodesic_m: float,
                  rng: np.random.Generator, settings: RouteSettings) -> list[tuple[float, float, float]]:
    """Up to ``n`` seeded start poses on floor ``s`` from which stairs lead to floor ``f``'s goal."""
    planner = building.planners[s]
    # the distance to the nearest stair end on floor s that leads on: a cheap filter before the exact sequence
    fields = [building.stair_end_field(lk, s) for lk in building.links if s in (lk.lower, lk.upper)]
    fields = [fld for fld in fields if fld is not None]
    if not fields:
        return []
    near = np.min(np.stack(fields), axis=0)
    cells = np.argwhere(planner.plan_mask & np.isfinite(near) & (near >= min_geodesic_m / 2))
    if not len(cells):
        return []
    out = []
    headings = int(round(360 / settings.turn_deg))
    for i in rng.permutation(len(cells)):
        xy = planner.grid.cell_to_world(cells[i])
        found = building.stair_sequence(s, xy, f, goal_field)
        if found is None or found[0] < min_geodesic_m:
            continue
        yaw = float(rng.integers(0, headings)) * math.radians(settings.turn_deg)
        out.append((float(xy[0]), float(xy[1]), float(math.atan2(math.sin(yaw), math.cos(yaw)))))
        if len(out) == n:
            break
    return out


def _cross_episode(building: BuildingPlanner, eid: str, goal: GoalTarget, aims: GoalTargets, s: int, f: int,
                   start, goal_field: np.ndarray, task: TaskParams, settings: RouteSettings
                   ) -> tuple[Episode | None, str]:
    """The verified cross-floor episode from ``start`` on floor ``s`` to ``goal`` on floor ``f``, or (None, why)."""
    route = building.route_to_goal(s, start, f, aims, key=goal.id, face_xy=goal.face_xy)
    if route is None:
        return None, "no route through the stairs"
    geodesic, _ = building.stair_sequence(s, start[:2], f, goal_field)
    pose = tuple(float(v) for v in start)
    res = None
    for i, (floor, leg) in enumerate(route.legs):
        planner = building.planners[floor]
        last = i == len(route.legs) - 1
        acts = np.zeros(1, np.uint8) if leg is None else leg.actions
        res = replay(acts, pose, planner.navigable, planner.grid, goal.footprints if last else [],
                     step_m=settings.step_m, turn_deg=settings.turn_deg, success_m=task.success_m,
                     region=goal.region if last else None, face_xy=goal.face_xy if last else None,
                     hfov_deg=task.hfov_deg if last else None)
        if res.collisions:
            return None, f"replay failed: {res.collisions} collisions on floor {floor}"
        if last:
            break
        climb = route.climbs[i]
        near = climb.link.end_on(floor)
        rc = planner.grid.world_to_cell(np.asarray(res.final_xyyaw[:2]))
        at_stair = building.stair_end_cells(climb.link, floor)
        if not (planner.grid.inside(rc) and at_stair[rc[0], rc[1]]):
            return None, f"replay failed: the walk on floor {floor} ends {math.dist(res.final_xyyaw[:2], near):.2f} " \
                         f"m from {climb.link.id}, off the cells within {STAIR_END_RADIUS_M} m of its end"
        far = climb.link.end_on(climb.link.other(floor))
        pose = (float(far[0]), float(far[1]), math.atan2(far[1] - near[1], far[0] - near[0]))
    if not res.success:
        return None, ("replay failed: ends outside the goal region" if not res.in_region else
                      "replay failed: ends not facing the goal" if not res.facing else
                      f"replay failed: ends {res.distance_to_goal_m:.2f} m away")
    legs = [leg for _, leg in route.legs]
    paths = [leg.path.polyline_xy for leg in legs if leg is not None]
    ep = Episode(eid, goal.id, tuple(float(v) for v in start), float(geodesic), np.concatenate(paths),
                 float(route.length_m), route.actions, route.text, len(route.parts) + len(route.climbs),
                 res.distance_to_goal_m, True, 0)
    ep.start_floor, ep.floors = s, tuple(route.floors)
    ep.leg_points = tuple(0 if leg is None else len(leg.path.polyline_xy) for leg in legs)
    ep.segments = tuple(route.segments)
    return ep, ""
