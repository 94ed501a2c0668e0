"""Goals + recon's navigable grid -> episodes with verified geodesic routes (``routes.zarr``): the routes stage's work.

Per goal: the goal region (:func:`pipeline.routes.region.goal_region`: navigable cells within
``routes.success_m`` of a member's footprint that see its mass centre, line of sight by ray casting
the reconstructed mesh from the recording's median camera height), seeded start poses at least
``routes.min_geodesic_m`` away (geodesic), the FMM shortest path into the region, its discrete
actions and procedural text; every route is replayed on the navigable grid and only verified ones
are stored; unreachable goals (empty region, no start) are flagged. Format: :mod:`pipeline.routes.store`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pipeline.config import RoutesParams
from pipeline.errors import LineageError
from pipeline.goals.store import Goals
from pipeline.recon import Recon
from pipeline.routes.actions import RouteSettings
from pipeline.routes.episodes import GoalTarget, make_episodes
from pipeline.routes.region import (OWN_DILATION_CELLS, ROUTE_MARGIN_CELLS, SIGHT_LEVELS, SIGHT_METHOD, MeshSight,
                                    group_region, recorded_camera_height)
from pipeline.routes.store import write_routes


def build_routes(goals: Goals, recon: Recon, out_path: Path, attrs: dict, p: RoutesParams, *,
                 log: Callable[[str], None] = print,
                 progress: Callable[[Iterable, int, str], Iterable] | None = None) -> dict:
    """Episodes for every goal of ``goals`` on ``recon``'s grid, written to a new ``routes.zarr`` at ``out_path``
    (``attrs``: its artifact attrs). ``progress(iterable, total, description)`` wraps the loop over goals.
    Returns the summary figures (the stage's manifest summary)."""
    t0 = time.perf_counter()
    if goals.grid != recon.grid:
        raise LineageError(f"{goals.path}: goals grid {goals.grid} differs from recon grid {recon.grid}; "
                           f"rerun the goals stage")
    index = goals.object_index()
    keys = goals.object_keys
    cam_h = recorded_camera_height(recon.poses, recon.floor_z)
    sight = MeshSight.from_mesh(recon.mesh_path, floor_z=recon.floor_z, camera_height_m=cam_h, grid=recon.grid)
    targets = []
    for g in goals.goals:
        # a same_goal group: any member counts
        region = group_region(recon.navigable, index, keys, g.object_keys, goals.objects, recon.grid, sight,
                              success_m=p.success_m)
        centres = np.array([goals.objects[k].mass_center for k in g.object_keys], np.float64).reshape(-1, 2)
        targets.append(GoalTarget(g.id, np.isin(index, [keys.index(k) + 1 for k in g.object_keys]),
                                  list(g.footprints), centres, g.room_id, region))
    settings = RouteSettings.from_config(p)
    eps = make_episodes(recon.navigable, recon.grid, targets, episodes_per_goal=p.episodes_per_goal,
                        min_geodesic_m=p.min_geodesic_m, seed=p.seed, settings=settings, success_m=p.success_m,
                        hfov_deg=p.hfov_deg,
                        progress=(lambda it, description="": it) if progress is None else
                        (lambda it, description="": progress(it, len(targets), description)))
    write_routes(out_path, eps, grid=recon.grid, attrs=attrs,
                 step_m=p.step_m, turn_deg=p.turn_deg, success_m=p.success_m,
                 regions={t.id: t.region for t in targets},
                 region_attrs={"definition": "navigable cells within success_m of the footprint that see the mass "
                                             "centre (pipeline.routes.region.goal_region)",
                               "success_m": p.success_m, "stop_radius_m": p.stop_radius_m,
                               "margin_cells": ROUTE_MARGIN_CELLS, "hfov_deg": p.hfov_deg},
                 sight={"method": SIGHT_METHOD, "camera_height_m": round(cam_h, 4), "levels": list(SIGHT_LEVELS),
                        "tolerance_m": sight.tolerance, "own_dilation_cells": OWN_DILATION_CELLS})
    n = eps.generated
    for u in eps.unreachable:
        log(f"goal {u['goal']} unreachable: {u['reason']}")
    for r in eps.rejected:
        log(f"episode {r['episode']} rejected: {r['reason']}")
    lengths = [e.geodesic_m for e in eps.episodes]
    return {
        "goals": len(targets), "unreachable_goals": len(eps.unreachable), "episodes": len(eps.episodes),
        "generated": n, "replay_verified_share": round(len(eps.episodes) / n, 4) if n else None,
        "mean_geodesic_m": round(float(np.mean(lengths)), 3) if lengths else None,
        "seconds": round(time.perf_counter() - t0, 3),
    }
