"""Episodes tau = (scene, goal, p0): seeded start poses, geodesic routes, actions, text, replay verdict.

The goal region is :func:`pipeline.nav.region.goal_region` (navigable cells within the success
distance from which the goal's mass centre is in line of sight on the reconstruction), given per
goal; routes aim for its :func:`~pipeline.nav.region.route_aims` (the route target, then narrower
margins, then the region; the first whose replay verifies). For each goal, start cells
are drawn (seeded) among cells of the clearance mask that reach the target with clearance and whose
FMM distance to the region is at least ``min_geodesic_m``; the heading is one of the
``360 / turn_deg`` lattice headings. The reference length ``l`` (for SPL) is the FMM geodesic
distance on the navigable mask from p0 to the goal REGION (the stored route aims a little inside
it and may keep some clearance: ``path_length_m``). Every episode's actions are replayed
(:mod:`pipeline.nav.verify`, which also checks that the walk ends in the region facing the
goal); only verified episodes are kept, the others are reported; goals with an empty region or no
reachable start are flagged unreachable.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.config import TaskParams
from pipeline.geometry import GridSpec
from pipeline.nav.actions import RoutePlanner, RouteSettings, route_text
from pipeline.nav.region import route_aims
from pipeline.nav.verify import replay


@dataclass
class GoalTarget:
    id: str
    object_mask: np.ndarray  # (rows, cols) bool footprint of the same_goal group
    footprints: list[np.ndarray]  # world polygons
    face_xy: np.ndarray  # (2,) or (K,2) mass centre(s) the agent turns to at the end (the nearest)
    room_id: str | None = None
    region: np.ndarray | None = None  # (rows, cols) bool goal region (pipeline.nav.region); None = stop radius


@dataclass
class Episode:
    id: str
    goal_id: str
    start: tuple[float, float, float]  # x, y, yaw (world metres, rad)
    geodesic_m: float  # reference shortest-path length l
    path_xy: np.ndarray  # (K,2) polyline, world metres
    path_length_m: float
    actions: np.ndarray  # (A,) uint8
    instruction: str
    n_parts: int
    final_distance_m: float
    verified: bool
    collisions: int
    # a building's episode: the floor it starts on, the floors it walks (in order) and the points of each floor's leg
    # in ``path_xy`` (a stair lies between consecutive legs); () in a single-floor scene
    start_floor: int = 0
    floors: tuple[int, ...] = ()
    leg_points: tuple[int, ...] = ()
    segments: tuple[int, ...] = ()  # actions per piece: leg, climb, leg, ... (the last leg with the stop)


@dataclass
class EpisodeSet:
    episodes: list[Episode] = field(default_factory=list)  # verified only
    rejected: list[dict] = field(default_factory=list)  # failed replays (id, reason)
    unreachable: list[dict] = field(default_factory=list)  # goals with no start (id, reason)

    @property
    def generated(self) -> int:
        return len(self.episodes) + len(self.rejected)


def sample_starts(fld: np.ndarray, plan_mask: np.ndarray, grid: GridSpec, n: int, min_geodesic_m: float,
                  rng: np.random.Generator, turn_deg: float) -> list[tuple[float, float, float]]:
    """Up to ``n`` distinct start poses with geodesic distance >= ``min_geodesic_m`` (seeded)."""
    ok = plan_mask & np.isfinite(fld) & (fld >= min_geodesic_m)
    cells = np.argwhere(ok)
    if len(cells) == 0:
        return []
    pick = rng.choice(len(cells), size=min(n, len(cells)), replace=False)
    headings = int(round(360 / turn_deg))
    xy = grid.cell_to_world(cells[np.sort(pick)])
    yaws = rng.integers(0, headings, size=len(xy)) * np.deg2rad(turn_deg)
    return [(float(x), float(y), float(np.arctan2(np.sin(a), np.cos(a)))) for (x, y), a in zip(xy, yaws)]


def make_episodes(navigable: np.ndarray, grid: GridSpec, goals: list[GoalTarget], *, episodes_per_goal: int,
                  min_geodesic_m: float, seed: int, task: TaskParams | None = None,
                  progress=lambda it, **kw: it) -> EpisodeSet:
    """Episodes for every goal (the per-goal seed is ``(seed, goal index)``), planned and replayed with the
    ``task``'s action space, stop radius, clearance, success radius and field of view (default: the params'
    defaults).

    A goal without ``region`` falls back to the cells within ``task.stop_radius_m`` of its footprint
    (no line-of-sight test; kept for callers without a reconstruction mesh)."""
    task = TaskParams() if task is None else task
    planner = RoutePlanner(navigable, grid, RouteSettings.from_config(task))
    planner.raise_failures = True  # an undrivable route is reported as rejected, with its reason
    out = EpisodeSet()
    for gi, goal in enumerate(progress(goals, description="episodes")):
        _goal_episodes(planner, goal, np.random.default_rng([seed, gi]), out, navigable=navigable, grid=grid,
                       episodes_per_goal=episodes_per_goal, min_geodesic_m=min_geodesic_m, task=task)
        planner.forget(goal.id)  # its fields: memory for one goal's at a time, not every goal's
    return out


def _goal_episodes(planner: RoutePlanner, goal: GoalTarget, rng: np.random.Generator, out: EpisodeSet, *,
                   navigable: np.ndarray, grid: GridSpec, episodes_per_goal: int, min_geodesic_m: float,
                   task: TaskParams) -> None:
    """:func:`make_episodes`' work for one goal: its episodes, rejections or unreachability added to ``out``."""
    settings, success_m = planner.settings, task.success_m
    if goal.region is not None:
        if not goal.region.any():
            out.unreachable.append({"goal": goal.id, "reason": f"empty goal region: no navigable cell within "
                                    f"{success_m} m of the object sees its mass centre"})
            return
        # aim inside the region first (route_aims: the route target, narrower margins, the region
        # itself); an aim a start cannot reach, or whose replay fails, gives way to the next
        aims = [((goal.id, name), mask) for name, mask in
                route_aims(goal.region, goal.object_mask, grid, stop_radius_m=settings.stop_radius_m)]
        fld = planner.field((goal.id, "region"), goal.region, "navigable", region=True)  # l: to the region
        reach_clear = planner.reach(goal.region, "clear", region=True)  # where its field on the clearance mask is finite
    else:
        aims = [(goal.id, goal.object_mask)]
        fld = planner.field(goal.id, goal.object_mask, "navigable")
        reach_clear = planner.reach(goal.object_mask, "clear")
    as_region = goal.region is not None
    if not reach_clear.any():  # no target cell on the clearance mask (those would be reached, at 0)
        out.unreachable.append({"goal": goal.id, "reason": "no cell with clearance in the goal region"})
        return
    # starts that reach the goal with clearance (robust to drive), l (navigable mask) >= min_geodesic_m
    both = np.where(reach_clear, fld, np.inf)
    starts = sample_starts(both, planner.plan_mask, grid, episodes_per_goal, min_geodesic_m, rng,
                           settings.turn_deg)
    if not starts:
        out.unreachable.append({"goal": goal.id,
                                "reason": f"no navigable start at least {min_geodesic_m} m away (geodesic)"})
        return
    for j, start in enumerate(starts):
        eid = f"{goal.id}/{j}"
        rc = grid.world_to_cell(np.asarray(start[:2]))
        reference_m = float(fld[rc[0], rc[1]])  # FMM on the navigable mask: the shortest length l
        ep, why = None, "no route from the start"
        for key, aim in aims:
            try:
                route = planner.route(start, aim, key=key, face_xy=goal.face_xy, region=as_region,
                                      end_mask=goal.region)  # the walk finishes inside the region
            except ValueError as err:  # descent or action budget failure: report, never keep
                why = str(err)
                continue
            if route is None:
                continue
            res = replay(route.actions, start, navigable, grid, goal.footprints, step_m=settings.step_m,
                         turn_deg=settings.turn_deg, success_m=success_m, region=goal.region,
                         face_xy=goal.face_xy if as_region else None, hfov_deg=task.hfov_deg)
            ep = Episode(eid, goal.id, start, reference_m, route.path.polyline_xy, route.path.length_m,
                         route.actions, route_text(route.parts), len(route.parts), res.distance_to_goal_m,
                         res.success, res.collisions)
            if res.success:
                break
            why = ("replay failed: " +
                   (f"{res.collisions} collisions" if res.collisions else
                    f"ends {res.distance_to_goal_m:.2f} m away" if res.distance_to_goal_m > success_m else
                    "ends outside the goal region (no line of sight)" if not res.in_region else
                    "ends not facing the goal"))
        if ep is not None and ep.verified:
            out.episodes.append(ep)
        else:
            out.rejected.append({"episode": eid, "reason": why})

