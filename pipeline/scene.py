"""One scene's artifacts, opened lazily: the handle the evaluator, the demo, the annotation server and the Python
API (:class:`zipon.Scene`) share.

:class:`Scene` gives the frames (ground truth), the reconstruction, the two semantic maps (as :class:`MapView`
objects, and as :class:`~pipeline.maps.query.MapQuery` for the evaluator), the goals and the routes of one scene.
Which stage produces which artifact is read from the stage registry it is given (``stages.STAGES``, passed in: the
library does not import the stage modules). On an object-store data root a ``fetch(stage)`` callback brings the
published version of a stage into the local mirror before its artifact is first read.

Before anything is evaluated, :meth:`Scene.check_lineage` compares the reconstruction's output digest
(``manifests/<scene>/reconstruct.json``) with the ``recon`` input digest recorded in each downstream manifest
(vlmap, cfmap, goals, routes) and the goals digest recorded by routes; any mismatch is a
:class:`~pipeline.errors.LineageError` naming both manifests.

The action space (``step_m``, ``turn_deg``) and the success radius are facts of ``routes.zarr``: the episodes'
reference paths and replays were made with them (and the goal regions of goals.zarr cut with that radius), so the
evaluator reads them from the artifact (:meth:`Scene.action_space`), never from the params.
:meth:`Scene.check_action_space` (run with the lineage check) refuses a ``task`` section that disagrees with the
artifact: ``task.step_m``, ``task.turn_deg``, ``task.success_m`` or ``task.hfov_deg`` differing from what
routes.zarr was built with (rebuild: ``zipon run``) — so one evaluation never mixes two action spaces, two success
radii or two fields of view.
"""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

import numpy as np

from pipeline.config import Params
from pipeline.errors import ConfigError, InputDataError, LineageError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.engine.manifest import Manifest
from pipeline.paths import Workspace

if TYPE_CHECKING:
    from pipeline.engine.stagegraph import StageSpec

MAP_NAMES = ("vlmap", "cfmap")
#: the artifacts a Scene reads
READ_ARTIFACTS = ("frames", "recon", "vlmap", "cfmap", "goals", "routes")
#: the stages whose artifacts are evaluated together, and the upstream outputs they must all share
CHECKED_STAGES = ("vlmap", "cfmap", "goals", "routes")
SHARED_INPUTS = ("recon", "goals")


def producers(stages: Mapping[str, "StageSpec"]) -> dict[str, str]:
    """``{artifact: the stage that writes it}`` from a stage registry."""
    return {out: spec.name for spec in stages.values() for out in spec.outputs}


def read_stages(stages: Mapping[str, "StageSpec"]) -> tuple[str, ...]:
    """The stages whose artifacts a :class:`Scene` reads, in :data:`READ_ARTIFACTS` order."""
    made_by = producers(stages)
    return tuple(dict.fromkeys(made_by[a] for a in READ_ARTIFACTS))


class Scene:
    """Read-only, lazily opened view of one scene's artifacts (see the module docstring).

    ``stages``: the stage registry (``stages.STAGES``). ``fetch(stage)``: brings a stage's published artifacts into
    the local mirror (object-store data roots), None for a local root. ``check``: run the lineage and action-space
    checks now (what the evaluator does before it reads anything).
    """

    def __init__(self, workspace: Workspace, params: Params, name: str, stages: Mapping[str, "StageSpec"], *,
                 fetch: Callable[[str], None] | None = None, check: bool = False):
        self.workspace, self.params, self.name = workspace, params, name
        self.stages, self.producer, self.fetch = stages, producers(stages), fetch
        if check:
            self.check_lineage()
            self.check_action_space()

    def __repr__(self) -> str:
        have = [a for a in READ_ARTIFACTS if self.workspace.artifact(a, self.name).exists()]  # no download
        return f"Scene({self.name!r}, artifacts={have})"

    def path(self, artifact: str) -> Path:
        """Where ``artifact`` ('frames', 'recon', 'vlmap', ...) of this scene lives (it may not exist yet). On an
        object-store data root the published version of its stage is brought into the local mirror first."""
        if self.fetch is not None and artifact in self.producer:
            self.fetch(self.producer[artifact])
        return self.workspace.artifact(artifact, self.name)

    def mirror(self) -> None:
        """Bring every stage this scene reads into the local mirror (nothing happens on a local data root)."""
        if self.fetch is not None:
            for stage in read_stages(self.stages):
                self.fetch(stage)

    def existing(self, artifact: str) -> Path:
        """:meth:`path`, or a MissingInputError naming the stage that builds it when it does not exist."""
        p = self.path(artifact)
        if not p.exists():
            raise MissingInputError(f"{p}: scene {self.name!r} has no {artifact} yet "
                                    f"(build it: zipon run -s {self.name} --stage {self.producer[artifact]})")
        return p

    # ------------------------------------------------------------------ lineage
    def manifest(self, stage: str) -> Manifest:
        man = Manifest.read(self.workspace.manifest(self.name, stage))
        if man is None:
            raise MissingInputError(f"{self.workspace.manifest(self.name, stage)}: no manifest of stage {stage} for scene "
                                    f"{self.name!r} (run: zipon run -s {self.name})")
        return man

    def lineage(self, stage: str) -> dict[str, str]:
        """``{input: producing stage}`` of the inputs of ``stage`` that every evaluated artifact must share."""
        return {name: self.producer[name] for name in self.stages[stage].inputs if name in SHARED_INPUTS}

    def check_lineage(self, stages: tuple[str, ...] = CHECKED_STAGES) -> dict[str, str]:
        """Raise :class:`LineageError` unless every downstream artifact comes from the same recon (and goals).

        Returns ``{artifact: digest}`` of the shared upstream outputs.
        """
        shared: dict[str, str] = {}
        for stage in stages:
            man = self.manifest(stage)
            for name, producer in self.lineage(stage).items():
                if name not in shared:
                    up = self.manifest(producer)
                    if name not in up.outputs:
                        raise LineageError(f"{self.workspace.manifest(self.name, producer)}: has no output {name!r}")
                    shared[name] = up.outputs[name].digest
                got = man.inputs.get(name)
                if got != shared[name]:
                    raise LineageError(
                        f"scene {self.name}: {stage} was built from {name} {got}, but "
                        f"{self.workspace.manifest(self.name, self.producer[name])} records {name} {shared[name]} "
                        f"(manifest {self.workspace.manifest(self.name, stage)}); rerun: zipon run -s {self.name}")
        return shared

    def action_space(self) -> tuple[float, float, float]:
        """``(step_m, turn_deg, success_m)`` that routes.zarr was built with (what the evaluator uses)."""
        r = self.routes
        return r.step_m, r.turn_deg, r.success_m

    def check_action_space(self) -> None:
        """Raise :class:`LineageError` when the params in force disagree with routes.zarr's action space or
        success radius (see the module docstring)."""
        step_m, turn_deg, success_m = self.action_space()
        task, src = self.params.task, self.workspace.params_path
        for key, built in (("step_m", step_m), ("turn_deg", turn_deg), ("success_m", success_m),
                           ("hfov_deg", self.routes.hfov_deg)):
            ours = getattr(task, key)
            if not math.isclose(ours, built, rel_tol=0.0, abs_tol=1e-9):
                raise LineageError(f"task.{key} {ours:g} in {src} but routes.zarr of {self.name} was built with "
                                   f"{built:g}: rebuild with zipon run -s {self.name}")

    # ------------------------------------------------------------------ artifacts
    @cached_property
    def frames(self):
        """:class:`~pipeline.frames.FrameStore`: rgb, depth (mm), pose (T_world_camera), stamp (ns)."""
        from pipeline.frames import FrameStore

        return FrameStore(self.existing("frames"))

    @cached_property
    def gt(self):
        """The scene's :class:`~pipeline.scene_gt.GTScene` (simulated scenes), else ``None``."""
        return self.frames.ground_truth

    @cached_property
    def recon(self):
        """:class:`~pipeline.recon.Recon`: occupancy, navigable, color, height grids; ``mesh_path``."""
        from pipeline.recon import Recon

        return Recon(self.existing("recon"))

    @cached_property
    def grid(self) -> GridSpec:
        return self.recon.grid

    @property
    def floors(self) -> tuple:
        """The scene's :class:`~pipeline.recon.store.Floor` s, lowest first (one for a single-floor scene); each
        floor's grids: ``scene.recon.floor(i)``."""
        return self.recon.floors

    @property
    def stairs(self) -> tuple:
        """The :class:`~pipeline.recon.store.StairLink` s joining the floors (none for a single floor)."""
        return self.recon.stairs

    @cached_property
    def navigable(self) -> np.ndarray:
        return self.recon.navigable

    @cached_property
    def height(self) -> np.ndarray:
        return self.recon.height

    @cached_property
    def goals(self):
        """:class:`~pipeline.goals.store.Goals`: ``.goals`` (GoalView list), ``.objects``, ``.document``."""
        from pipeline.goals.store import Goals

        return Goals(self.existing("goals"))

    @cached_property
    def routes(self):
        """:class:`~pipeline.routes.store.Routes`: verified episodes with geodesic paths and actions."""
        from pipeline.routes.store import Routes

        return Routes(self.existing("routes"))

    @property
    def episodes(self) -> list:
        """The routes' episodes (:class:`~pipeline.routes.store.EpisodeView`: id, goal_id, start, path_xy, ...)."""
        return self.routes.episodes

    @cached_property
    def vlmap(self) -> "MapView":
        return MapView(self, "vlmap")

    @cached_property
    def cfmap(self) -> "MapView":
        return MapView(self, "cfmap")

    def map(self, which: str) -> "MapView":
        if which not in MAP_NAMES:
            raise ConfigError(f"map {which!r}: choose one of {list(MAP_NAMES)}")
        return getattr(self, which)

    def map_query(self, which: str, floor: int = 0):
        """The cached :class:`~pipeline.maps.query.MapQuery` of ``'vlmap'`` or ``'cfmap'`` on floor ``floor``."""
        from pipeline.maps.query import open_query

        return open_query(self.existing(which), self.params, recon_path=self.existing("recon"),
                          frames_path=self.workspace.artifact("frames", self.name), floor=floor)

    @cached_property
    def camera_height_m(self) -> float:
        """Ego camera height above the floor: ``eval.camera_height_m`` or the recording's median."""
        if self.params.eval.camera_height_m is not None:
            return float(self.params.eval.camera_height_m)
        from pipeline.nav.region import recorded_camera_height

        return recorded_camera_height(self.recon.poses, self.recon.floor_z)  # what the routes stage sighted from

    @cached_property
    def room_of_cell(self) -> tuple[np.ndarray, list[str]]:
        """``(rows, cols)`` int16 room index (-1 none) and the room ids, from the goals' object rooms / GT rooms."""
        import cv2

        g = self.grid
        out = np.full((g.rows, g.cols), -1, np.int16)
        ids: list[str] = []
        rooms = self.gt.rooms if self.gt is not None else []
        for i, room in enumerate(rooms):
            rc = g.world_to_cell(np.asarray(room.polygon)).astype(np.int32)
            m = np.zeros((g.rows, g.cols), np.uint8)
            cv2.fillPoly(m, [rc[:, ::-1].reshape(-1, 1, 2)], 1)
            out[m.astype(bool)] = i
            ids.append(room.id)
        return out, ids

    def room_at(self, xy) -> str | None:
        """Room id at a world point (simulated scenes), else ``None``."""
        idx, ids = self.room_of_cell
        rc = self.grid.world_to_cell(np.asarray(xy, dtype=np.float64))
        if not self.grid.inside(rc) or idx[rc[0], rc[1]] < 0:
            return None
        return ids[int(idx[rc[0], rc[1]])]


class MapView:
    """A semantic map of a scene: text queries, the dense xarray grid, features at world points.

    ``floor``: the floor (an index, lowest first) this view shows; None (``scene.vlmap``) is the whole scene:
    its queries answer from every floor, and its grid, features and xarray are floor 0's (the only floor of a
    single-floor scene). ``view.floors`` (one view per floor) and ``view.floor(k)`` give each floor.
    """

    def __init__(self, scene: Scene, which: str, floor: int | None = None):
        self.scene, self.which, self.floor_index = scene, which, floor
        self.path = scene.existing(which)
        if floor is not None:
            from pipeline.maps.store import SemanticMap

            n_floors = len(SemanticMap(self.path).floors)
            if not 0 <= floor < n_floors:
                raise InputDataError(f"got {floor}", field="floor",
                                     expected=f"a floor of scene {scene.name!r}: 0..{n_floors - 1}")

    def __repr__(self) -> str:
        s = self.store
        where = "" if self.floor_index is None else f", floor={self.floor_index}"
        return (f"MapView({self.scene.name!r}, {self.which!r}{where}, encoder={s.encoder.get('name')!r}, "
                f"cells={s.n_cells})")

    @cached_property
    def store(self):
        """The :class:`~pipeline.maps.store.SemanticMap` reader (of this view's floor; floor 0 for the whole scene)."""
        from pipeline.maps.store import SemanticMap

        return SemanticMap(self.path, self.floor_index or 0)

    @property
    def floors(self) -> list["MapView"]:
        """One view per floor of the map, lowest first."""
        return [self.floor(k) for k in range(len(self.store.floors))]

    def floor(self, index: int) -> "MapView":
        """The view of floor ``index`` (lowest first)."""
        return MapView(self.scene, self.which, index)

    @property
    def grid(self):
        return self.store.grid

    @property
    def encoder(self) -> dict:
        return dict(self.store.encoder)

    def _query(self, floor: int):
        from pipeline.maps.query import open_query

        sc = self.scene
        recon = sc.path("recon")
        return open_query(self.path, sc.params, recon_path=recon if recon.exists() else None,
                          frames_path=sc.path("frames"), floor=floor)

    def query(self, text: str, pose: Sequence[float] | None = None, *, pose_floor: int = 0, region=None):
        """Heatmap and object candidates for ``text``.

        ``region`` = (x0, y0, x1, y1) world metres (or a :class:`~pipeline.region.Region`) scores only the cells in
        it, reading only the map's tiles it meets; the result's grid, heatmap and cells are then the region's.

        ``pose`` = (x, y, yaw): world metres and radians (counter-clockwise from +x); candidates are then
        sorted by distance and carry ``distance_m`` / ``angle_rad`` from it. A pose off the map's grid is
        an :class:`~pipeline.errors.InputDataError`. On one floor (a view of one floor, or a single-floor scene):
        a :class:`~pipeline.maps.query.QueryResult`. On a building's whole-scene view: a
        :class:`~pipeline.maps.floors.FloorsResult`, every floor's candidates with their ``floor``; the pose then
        stands on floor ``pose_floor``.
        """
        n_floors = len(self.store.floors)
        if self.floor_index is not None or n_floors == 1:
            if pose is not None:
                pose = check_pose(self.grid, pose, field="pose")
            return self._query(self.floor_index or 0).query(text, pose, region=_region(region))
        from pipeline.maps.floors import query_floors

        if pose is not None:
            if not 0 <= pose_floor < n_floors:
                raise InputDataError(f"got {pose_floor}", field="pose_floor", expected=f"a floor 0..{n_floors - 1}")
            pose = check_pose(self.store.floor_map(pose_floor).grid, pose, field="pose")
        return query_floors([self._query(k) for k in range(n_floors)], text, pose, pose_floor=pose_floor,
                            region=_region(region))

    def features_at(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """Features ``(K,D)`` float32 at world points ``xy`` ``(K,2)`` metres and a ``(K,)`` bool observed mask
        (rows of unobserved or off-grid points are zeros); reads only the tiles holding the points."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return self.store.features_at(self.grid.world_to_cell(xy))

    def to_xarray(self, region=None):
        """The map as an ``xarray.Dataset`` on its dense grid, or on the cells of ``region`` = (x0, y0, x1, y1)
        world metres; lazy: features are read tile by tile when computed (see :func:`map_to_xarray`)."""
        return map_to_xarray(self.store, _region(region))


def _region(region):
    """A :class:`~pipeline.region.Region` from ``(x0, y0, x1, y1)`` (or one already), None for None; an
    InputDataError naming ``region`` when it is not four finite numbers of a non-empty box."""
    from pipeline.region import Region, parse_region

    return region if region is None or isinstance(region, Region) else parse_region(region, "region")


def check_pose(grid, pose: Sequence[float], *, field: str) -> tuple[float, float, float]:
    """``(x, y, yaw)`` as floats, or an InputDataError when it is not three finite numbers or lies off ``grid``."""
    try:
        x, y, yaw = (float(v) for v in pose)
    except (TypeError, ValueError):
        raise InputDataError(f"got {pose!r}", field=field, expected="(x, y, yaw): metres, metres, angle") from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise InputDataError(f"got {pose!r}", field=field, expected="finite numbers")
    x0, x1, y0, y1 = grid.extent_xy
    if not (x0 <= x < x1 and y0 < y <= y1):
        raise InputDataError(f"position ({x:g}, {y:g}) m lies off the map's grid", field=field,
                             expected=f"x in [{x0:.2f}, {x1:.2f}) and y in ({y0:.2f}, {y1:.2f}] metres")
    return x, y, yaw


def grid_coords(grid) -> dict[str, np.ndarray]:
    """Cell-centre coordinates (metres) of a north-up grid: ``y`` falls with the row, ``x`` grows with the column."""
    x = grid.origin_xy[0] + (np.arange(grid.cols) + 0.5) * grid.cell_size_m
    y = grid.origin_xy[1] - (np.arange(grid.rows) + 0.5) * grid.cell_size_m
    return {"y": y, "x": x}


def map_to_xarray(smap, region=None):
    """A :class:`~pipeline.maps.store.SemanticMap` as ``xarray.Dataset`` on dims ``(y, x[, feature])``.

    ``features`` ``(y, x, feature)`` float16 is a lazy dask array, one block per stored tile, each read from the
    store only when computed (NaN where unobserved), so a map of any size costs nothing until sliced; ``observed``,
    ``weight``, ``count`` and ``top_z`` (world z of the cell's top level, metres) are ``(y, x)``, read for the
    cells covered only. ``region`` (a :class:`~pipeline.region.Region`, world metres) covers only its cells (an
    InputDataError naming ``region`` when it misses the grid), reading only the tiles it meets.
    Coordinates ``x``, ``y`` are world metres of the cell centres; units are in each variable's attrs.
    """
    import dask.array as da
    import xarray as xr

    from pipeline.region import region_window

    window = region_window(smap.grid, region, "region")
    g = window.grid(smap.grid)
    index = smap.index_in(window)
    ok = index >= 0
    rows = index[ok].astype(np.int64)
    dim = smap.dim
    tile = smap.tile_cells

    def gather(block: np.ndarray) -> np.ndarray:  # one tile's part: its rows are one contiguous range of top/*
        out = np.full(block.shape + (dim,), np.nan, np.float16)
        m = block >= 0
        if m.any():
            s, e = int(block[m].min()), int(block[m].max()) + 1
            out[m] = smap.read_rows(s, e)[1][block[m] - s]
        return out

    def cuts(lo: int, hi: int) -> tuple[int, ...]:  # block sizes along one axis, cut at the tiles' edges
        edges = [lo, *range((lo // tile + 1) * tile, hi, tile), hi]
        return tuple(b - a for a, b in zip(edges[:-1], edges[1:]))

    lazy_index = da.from_array(index, chunks=(cuts(window.r0, window.r1), cuts(window.c0, window.c1)),
                               name=f"zipon-index-{smap.path}-{smap.floor_index}-{window}")
    features = lazy_index.map_blocks(gather, new_axis=2, chunks=lazy_index.chunks + ((dim,),), dtype=np.float16,
                                     name=f"zipon-features-{smap.path}-{smap.floor_index}-{window}")

    def dense(values: np.ndarray, fill, dtype) -> np.ndarray:
        out = np.full(index.shape, fill, dtype)
        out[ok] = values
        return out

    top_z = smap.lattice.level_z(smap.rows_of("level", rows))
    enc = {k: v for k, v in smap.encoder.items() if isinstance(v, (str, int, float, bool))}
    coords = grid_coords(g)
    ds = xr.Dataset(
        {
            "features": (("y", "x", "feature"), features,
                         {"units": "1", "long_name": f"unit L2-norm {enc.get('name')} feature, NaN = unobserved"}),
            "observed": (("y", "x"), ok, {"units": "1", "long_name": "cell has a feature"}),
            "weight": (("y", "x"), dense(smap.rows_of("weight", rows).astype(np.float32), np.nan, np.float32),
                       {"units": "1", "long_name": "sum of point weights fused into the cell"}),
            "count": (("y", "x"), dense(smap.rows_of("count", rows).astype(np.int32), -1, np.int32),
                      {"units": "points", "long_name": "points fused (0 = filled from a neighbour, -1 = unobserved)"}),
            "top_z": (("y", "x"), dense(top_z.astype(np.float32), np.nan, np.float32),
                      {"units": "m", "long_name": "world z of the level whose feature the cell holds"}),
        },
        coords={
            "y": ("y", coords["y"], {"units": "m", "long_name": "world y of the cell centre (north)"}),
            "x": ("x", coords["x"], {"units": "m", "long_name": "world x of the cell centre (east)"}),
            "feature": ("feature", np.arange(dim), {"units": "1", "long_name": "feature channel"}),
        },
        attrs={"artifact": smap.artifact, "path": str(smap.path), "cell_size_m": g.cell_size_m,
               "origin_xy": list(g.origin_xy), "orientation": g.ORIENTATION,
               "frame": "world: right-handed, z up, metres", **{f"encoder_{k}": v for k, v in enc.items()}},
    )
    return ds
