"""``routes.zarr``: verified episodes with geodesic paths and actions, and the evaluator's reader.

Format (version 3; version 2 added the goal regions and ``sight``, version 3 moved them to goals.zarr,
where the goals stage computes them once)::

    routes.zarr/        attrs: artifact="routes", format_version=3, stage, params_digest, code_version, scene,
    │                          units="metres, radians", frame="world, z up", grid {...},
    │                          action_space {codes {0: stop, 1: forward, 2: left, 3: right}, step_m, turn_deg},
    │                          success_m, goals_digest (content digest of the goals.zarr used),
    │                          episodes   [{id, goal_id, start [x, y, yaw], geodesic_m (= l for SPL),
    │                                      path_length_m, n_actions, instruction, n_parts, final_distance_m}]
    │                          verification {generated, verified, share, rejected [{episode, reason}]},
    │                          unreachable_goals [{goal, reason}],
    │                          goal_region {source: the goals.zarr regions, stop_radius_m, margin_cells, hfov_deg}
    ├── path_xy        (P,2) float64  every episode's polyline, concatenated (world metres)
    ├── path_offset    (E+1,) int64   episode e's polyline = path_xy[path_offset[e]:path_offset[e+1]]
    ├── actions        (A,) uint8     every episode's actions, concatenated (ending with 0 = stop)
    └── action_offset  (E+1,) int64   episode e's actions = actions[action_offset[e]:action_offset[e+1]]

A building's episodes (:mod:`pipeline.routes.floors`) also carry ``start_floor``, ``floors`` (the floors walked,
in order, a stair between each two), ``leg_points`` (each floor's leg's points in ``path_xy``) and ``segments``
(its actions per piece: leg, climb, leg, ...; the last leg ends with the stop); ``start`` and the
path are on those floors' grids. A single-floor store has none of these keys and is as before floors existed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

import numpy as np

from pipeline.errors import ArtifactError
from pipeline.geometry import GridSpec
from pipeline.nav.codes import ACTION_NAMES
from pipeline.store import ArtifactAttrs, AttrsModel, GridAttrs, compressor, new_group, open_group

ARTIFACT = "routes"
FORMAT_VERSION = 3

# ----------------------------------------------------------------------------- the store's types

#: the task's discrete actions, as stored in ``actions`` (pipeline.nav.actions plans with them)


class EpisodeSource(Protocol):
    """What :func:`write_routes` stores of an episode (:class:`pipeline.routes.episodes.Episode` is one)."""

    id: str
    goal_id: str
    start: tuple[float, float, float]
    geodesic_m: float
    path_xy: np.ndarray
    path_length_m: float
    actions: np.ndarray
    instruction: str
    n_parts: int
    final_distance_m: float


class EpisodeSetSource(Protocol):
    """The verified episodes, rejected replays and unreachable goals (:class:`pipeline.routes.episodes.EpisodeSet`)."""

    episodes: Sequence[EpisodeSource]
    rejected: list[dict]
    unreachable: list[dict]

    @property
    def generated(self) -> int: ...


class ActionSpace(AttrsModel):
    codes: dict[str, str]
    step_m: float
    turn_deg: float


class EpisodeRecord(AttrsModel):
    """One entry of ``attrs.episodes`` (its polyline and actions are rows of the arrays)."""

    id: str
    goal_id: str
    start: tuple[float, float, float]  # x, y, yaw
    geodesic_m: float
    path_length_m: float
    n_actions: int
    instruction: str
    n_parts: int
    final_distance_m: float
    # a building only: the floor it starts on, the floors it walks and each floor's leg's points in path_xy
    start_floor: int | None = None
    floors: list[int] | None = None
    leg_points: list[int] | None = None
    segments: list[int] | None = None  # actions per piece: leg, climb, leg, ... (the last leg with the stop)


class Verification(AttrsModel):
    generated: int
    verified: int
    share: float | None
    rejected: list[dict[str, Any]]


class RouteAimAttrs(AttrsModel):
    """``attrs.goal_region`` of routes.zarr: how episodes were aimed and replayed into the goal regions (what
    goals.zarr keeps under the same key, how the regions were cut, is :class:`pipeline.goals.store.GoalRegionAttrs`)."""

    hfov_deg: float | None = None
    stop_radius_m: float | None = None
    margin_cells: int | None = None


class RoutesAttrs(ArtifactAttrs):
    """The attrs of ``routes.zarr`` (the tree above)."""

    scene: str | None = None
    grid: GridAttrs
    action_space: ActionSpace
    success_m: float
    episodes: list[EpisodeRecord]
    verification: Verification
    unreachable_goals: list[dict[str, Any]]
    goal_region: RouteAimAttrs = RouteAimAttrs()


def write_routes(path: Path, eps: EpisodeSetSource, *, grid: GridSpec, attrs: dict, step_m: float, turn_deg: float,
                 success_m: float, region_attrs: dict | None = None) -> None:
    """Write ``routes.zarr`` (format above)."""
    records = [{
        "id": e.id, "goal_id": e.goal_id, "start": [round(v, 6) for v in e.start], "geodesic_m": round(e.geodesic_m, 4),
        "path_length_m": round(e.path_length_m, 4), "n_actions": int(len(e.actions)), "instruction": e.instruction,
        "n_parts": e.n_parts, "final_distance_m": round(e.final_distance_m, 4),
        **({"start_floor": e.start_floor, "floors": list(e.floors),
            "leg_points": list(e.leg_points or [len(e.path_xy)]), "segments": list(e.segments or [len(e.actions)])}
           if getattr(e, "floors", ()) else {}),
    } for e in eps.episodes]
    n = eps.generated
    group = new_group(Path(path), RoutesAttrs.checked({
        **attrs, "units": "metres, radians", "frame": "world, z up", "grid": grid.to_attrs(),
        "action_space": {"codes": {str(k): v for k, v in ACTION_NAMES.items()}, "step_m": step_m,
                         "turn_deg": turn_deg},
        "success_m": success_m, "episodes": records,
        "verification": {"generated": n, "verified": len(eps.episodes),
                         "share": (len(eps.episodes) / n) if n else None, "rejected": eps.rejected},
        "unreachable_goals": eps.unreachable, "goal_region": dict(region_attrs or {}),
    }, path))
    paths = [e.path_xy for e in eps.episodes]
    acts = [e.actions for e in eps.episodes]
    path_off = np.concatenate([[0], np.cumsum([len(p) for p in paths])]).astype(np.int64)
    act_off = np.concatenate([[0], np.cumsum([len(a) for a in acts])]).astype(np.int64)
    arrays = {
        "path_xy": np.concatenate(paths).astype(np.float64) if paths else np.zeros((0, 2)),
        "path_offset": path_off,
        "actions": np.concatenate(acts).astype(np.uint8) if acts else np.zeros(0, np.uint8),
        "action_offset": act_off,
    }
    for name, a in arrays.items():
        chunks = (max(len(a), 1),) + a.shape[1:]
        z = group.create_array(name, shape=a.shape, chunks=chunks, dtype=a.dtype, compressors=compressor(3))
        if a.size:
            z[:] = a


@dataclass(frozen=True)
class EpisodeView:
    id: str
    goal_id: str
    start: tuple[float, float, float]  # x, y, yaw
    geodesic_m: float  # reference length l for SPL
    path_xy: np.ndarray  # (K,2)
    actions: np.ndarray  # (A,) uint8
    instruction: str
    start_floor: int = 0  # a building: the floor it starts on
    floors: tuple[int, ...] = (0,)  # the floors it walks, in order (a stair between each two)
    leg_points: tuple[int, ...] = ()  # a building: each floor's leg's points in path_xy (empty: one leg)

    def legs(self) -> list[tuple[int, np.ndarray]]:
        """``[(floor, (K,2) xy)]``: the path cut into the legs walked on each floor, in order (one leg on one
        floor); a stair joins each leg's end to the next leg's start."""
        counts = self.leg_points or (len(self.path_xy),)
        ends = np.cumsum(counts)
        return [(int(f), self.path_xy[e - n: e]) for f, n, e in zip(self.floors, counts, ends)]


class Routes:
    """Read-only view of a ``routes.zarr``."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.group = open_group(self.path, artifact=ARTIFACT, format_version=FORMAT_VERSION)
        self.attrs = dict(self.group.attrs)
        self.meta = RoutesAttrs.read(self.attrs, self.path)
        self.grid = self.meta.grid.spec
        self.records = self.meta.episodes
        self._path_xy = self.group["path_xy"][:]
        self._path_off = self.group["path_offset"][:]
        self._actions = self.group["actions"][:]
        self._act_off = self.group["action_offset"][:]
        self._check_buildings()
        self.episodes = [self._view(i) for i in range(len(self.records))]

    def _check_buildings(self) -> None:
        """A building's episode records agree with the arrays: one leg per floor walked, starting on its first, the
        legs' points adding up to the episode's polyline (a store edited by hand otherwise slices legs silently)."""
        for i, r in enumerate(self.records):
            if r.floors is None and r.leg_points is None and r.start_floor is None:
                continue
            floors, legs = list(r.floors or []), list(r.leg_points or [])
            n_points = int(self._path_off[i + 1] - self._path_off[i])
            problem = ("floors is empty" if not floors else
                       f"a negative floor in floors {floors}" if min(floors) < 0 else
                       f"start_floor {r.start_floor} is not the first of floors {floors}"
                       if r.start_floor is not None and r.start_floor != floors[0] else
                       f"{len(legs)} leg_points for {len(floors)} floors" if len(legs) != len(floors) else
                       f"leg_points {legs} add up to {sum(legs)}, not the episode's {n_points} path points"
                       if min(legs) < 0 or sum(legs) != n_points else "")
            if problem:
                raise ArtifactError(f"{self.path}: attrs.episodes[{i}] ({r.id!r}): {problem}; rebuild the routes "
                                    "(zipon run --stage routes --force)")

    def _view(self, i: int) -> EpisodeView:
        r = self.records[i]
        return EpisodeView(r.id, r.goal_id, r.start, r.geodesic_m,
                           self._path_xy[self._path_off[i]: self._path_off[i + 1]],
                           self._actions[self._act_off[i]: self._act_off[i + 1]], r.instruction,
                           r.start_floor or 0, tuple(r.floors or (r.start_floor or 0,)), tuple(r.leg_points or ()))

    @property
    def step_m(self) -> float:
        """Forward action the routes were built with, metres (``action_space.step_m``)."""
        return self.meta.action_space.step_m

    @property
    def turn_deg(self) -> float:
        """Turn action the routes were built with, degrees (``action_space.turn_deg``)."""
        return self.meta.action_space.turn_deg

    @property
    def success_m(self) -> float:
        """Success radius the replays were checked with (= goals.zarr's regions'), metres."""
        return self.meta.success_m

    @property
    def hfov_deg(self) -> float:
        """Ego-view field of view the replays were checked with, degrees (``goal_region.hfov_deg``)."""
        if self.meta.goal_region.hfov_deg is None:
            raise ArtifactError(f"{self.path}: attrs.goal_region.hfov_deg missing (rebuild it with: zipon run --force)")
        return self.meta.goal_region.hfov_deg

    def for_goal(self, goal_id: str) -> list[EpisodeView]:
        return [e for e in self.episodes if e.goal_id == goal_id]

    @property
    def verification(self) -> dict:
        return self.meta.verification.model_dump(mode="json")

    @property
    def unreachable_goals(self) -> list[dict]:
        return list(self.meta.unreachable_goals)
