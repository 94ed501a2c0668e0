"""Goals + recon's navigable grid -> episodes with verified geodesic routes (``routes.zarr``): the routes stage's work.

Per goal: its goal region, read from ``goals.zarr`` (computed once by the goals stage:
:func:`pipeline.nav.region.group_region`, navigable cells within ``task.success_m`` of a member's
footprint that see its mass centre, line of sight by ray casting the reconstructed mesh), seeded start
poses at least ``routes.min_geodesic_m`` away (geodesic), the FMM shortest path into the region, its
discrete actions (the ``task``'s action space) and procedural text; every route is replayed on the
navigable grid and only verified ones are stored; unreachable goals (empty region, no start) are
flagged. Format: :mod:`pipeline.routes.store`.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pipeline.config import RoutesParams, TaskParams
from pipeline.errors import LineageError
from pipeline.goals.store import Goals
from pipeline.recon import Recon
from pipeline.routes.episodes import GoalTarget, make_episodes
from pipeline.nav.region import ROUTE_MARGIN_CELLS
from pipeline.routes.store import write_routes


def build_routes(goals: Goals, recon: Recon, out_path: Path, attrs: dict, p: RoutesParams, task: TaskParams, *,
                 log: Callable[[str], None] = print,
                 progress: Callable[[Iterable, int, str], Iterable] | None = None) -> dict:
    """Episodes for every goal of ``goals`` on ``recon``'s grid, written to a new ``routes.zarr`` at ``out_path``
    (``attrs``: its artifact attrs). ``progress(iterable, total, description)`` wraps the loop over goals.
    Returns the summary figures (the stage's manifest summary)."""
    t0 = time.perf_counter()
    if goals.grid != recon.grid:
        raise LineageError(f"{goals.path}: goals grid {goals.grid} differs from recon grid {recon.grid}; "
                           f"rerun the goals stage")
    if not math.isclose(goals.success_m, task.success_m, rel_tol=0.0, abs_tol=1e-9):
        raise LineageError(f"{goals.path}: goal regions cut with success_m {goals.success_m:g}, but task.success_m "
                           f"is {task.success_m:g}; rerun the goals stage")
    keys = goals.object_keys
    indexes = {f: goals.object_index(f) for f in range(len(recon.floors))}
    targets = []
    for g in goals.goals:
        centres = np.array([goals.objects[k].mass_center for k in g.object_keys], np.float64).reshape(-1, 2)
        targets.append(GoalTarget(g.id, np.isin(indexes[g.floor], [keys.index(k) + 1 for k in g.object_keys]),
                                  list(g.footprints), centres, g.room_id, goals.goal_region(g.id)))
    wrap = ((lambda it, description="": it) if progress is None else
            (lambda it, description="": progress(it, len(targets), description)))
    if len(recon.floors) > 1:  # a building: per floor, and from the other floors over the stairs
        from pipeline.nav.actions import RouteSettings
        from pipeline.nav.building import building_planner
        from pipeline.routes.floors import building_episodes

        building = building_planner(recon, RouteSettings.from_config(task))
        for f in building.unlinked():
            log(f"warning: {recon.floors[f].name} is joined to no other floor by stairs: its goals are reachable "
                "only from starts on it")
        per_floor = {f: [t for t, g in zip(targets, goals.goals) if g.floor == f] for f in range(len(recon.floors))}
        eps = building_episodes(building, per_floor, episodes_per_goal=p.episodes_per_goal,
                                cross_floor_per_goal=p.cross_floor_per_goal, min_geodesic_m=p.min_geodesic_m,
                                seed=p.seed, task=task, progress=wrap)
    else:
        eps = make_episodes(recon.navigable, recon.grid, targets, episodes_per_goal=p.episodes_per_goal,
                            min_geodesic_m=p.min_geodesic_m, seed=p.seed, task=task, progress=wrap)
    write_routes(out_path, eps, grid=recon.grid, attrs=attrs,
                 step_m=task.step_m, turn_deg=task.turn_deg, success_m=task.success_m,
                 region_attrs={"source": "goals.zarr (region_cells, region_offset)",
                               "stop_radius_m": task.stop_radius_m, "margin_cells": ROUTE_MARGIN_CELLS,
                               "hfov_deg": task.hfov_deg})
    n = eps.generated
    for u in eps.unreachable:
        log(f"goal {u['goal']} unreachable: {u['reason']}")
    for r in eps.rejected:
        log(f"episode {r['episode']} rejected: {r['reason']}")
    lengths = [e.geodesic_m for e in eps.episodes]
    cross = sum(len(e.floors) > 1 for e in eps.episodes)
    return {
        **({"floors": len(recon.floors), "cross_floor_episodes": cross} if len(recon.floors) > 1 else {}),
        "goals": len(targets), "unreachable_goals": len(eps.unreachable), "episodes": len(eps.episodes),
        "generated": n, "replay_verified_share": round(len(eps.episodes) / n, 4) if n else None,
        "mean_geodesic_m": round(float(np.mean(lengths)), 3) if lengths else None,
        "seconds": round(time.perf_counter() - t0, 3),
    }
