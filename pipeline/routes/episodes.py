"""Episodes tau = (scene, goal, p0): seeded start poses, geodesic routes, actions, text, replay verdict.

For each goal, start cells are drawn (seeded) among cells of the clearance mask whose FMM distance
to the goal region (on that mask) is at least ``min_geodesic_m``; the heading is one of the
``360 / turn_deg`` lattice headings. The reference length ``l`` (for SPL) is that FMM geodesic
distance on the navigable mask from p0 to the goal region (the stored route may keep some clearance
and be a little longer: ``path_length_m``). Every episode's actions are replayed (:mod:`pipeline.routes.verify`); only verified episodes
are kept, the others are reported; goals with no reachable start are flagged unreachable.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import GridSpec
from pipeline.routes.actions import RoutePlanner, RouteSettings, route_text
from pipeline.routes.verify import replay


@dataclass
class GoalTarget:
    id: str
    object_mask: np.ndarray  # (rows, cols) bool footprint of the same_goal group
    footprints: list[np.ndarray]  # world polygons
    face_xy: np.ndarray  # mass centre the agent turns to at the end
    room_id: str | None = None


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
                  min_geodesic_m: float, seed: int, settings: RouteSettings = RouteSettings(),
                  success_m: float = 1.5, progress=lambda it, **kw: it) -> EpisodeSet:
    """Episodes for every goal (the per-goal seed is ``(seed, goal index)``)."""
    planner = RoutePlanner(navigable, grid, settings)
    planner.raise_failures = True  # an undrivable route is reported as rejected, with its reason
    out = EpisodeSet()
    for gi, goal in enumerate(progress(goals, description="episodes")):
        rng = np.random.default_rng([seed, gi])
        # starts where the goal is reachable with clearance (robust to drive); l from the navigable mask
        fld_clear = planner.field(goal.id, goal.object_mask, "clear")
        fld = planner.field(goal.id, goal.object_mask, "navigable")
        if not np.isfinite(fld_clear).any() or not (fld_clear == 0).any():
            out.unreachable.append({"goal": goal.id, "reason": "no cell with clearance within the stop radius of the object"})
            continue
        both = np.where(np.isfinite(fld_clear), np.minimum(fld_clear, fld), np.inf)  # l >= min on either mask
        starts = sample_starts(both, planner.plan_mask, grid, episodes_per_goal, min_geodesic_m, rng,
                               settings.turn_deg)
        if not starts:
            out.unreachable.append({"goal": goal.id,
                                    "reason": f"no navigable start at least {min_geodesic_m} m away (geodesic)"})
            continue
        for j, start in enumerate(starts):
            eid = f"{goal.id}/{j}"
            try:
                route = planner.route(start, goal.object_mask, key=goal.id, face_xy=goal.face_xy)
            except ValueError as err:  # descent or action budget failure: report, never keep
                out.rejected.append({"episode": eid, "reason": str(err)})
                continue
            if route is None:
                out.rejected.append({"episode": eid, "reason": "no route from the start"})
                continue
            res = replay(route.actions, start, navigable, grid, goal.footprints, step_m=settings.step_m,
                         turn_deg=settings.turn_deg, success_m=success_m)
            rc = grid.world_to_cell(np.asarray(start[:2]))
            reference_m = float(fld[rc[0], rc[1]])  # FMM on the navigable mask: the shortest length l
            ep = Episode(eid, goal.id, start, reference_m, route.path.polyline_xy, route.path.length_m,
                         route.actions, route_text(route.parts), len(route.parts), res.distance_to_goal_m,
                         res.success, res.collisions)
            if res.success:
                out.episodes.append(ep)
            else:
                why = f"{res.collisions} collisions" if res.collisions else f"ends {res.distance_to_goal_m:.2f} m away"
                out.rejected.append({"episode": eid, "reason": f"replay failed: {why}"})
    return out
