"""``zipon.open`` -> :class:`Dataset` -> :class:`Scene` -> artifacts and :class:`MapView`.

Nothing here re-implements a reader: scenes hand out the stores' own readers
(:class:`~pipeline.frames.FrameStore`, :class:`~pipeline.recon.Recon`, :class:`~pipeline.goals.store.Goals`,
:class:`~pipeline.routes.store.Routes`) and maps query through :func:`pipeline.maps.query.open_query`
(cached, so repeated queries cost one product). Units are the project's: metres, radians, world z up.
"""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from pipeline.errors import ConfigError, InputDataError, MissingInputError
from pipeline.paths import PARAMS_FILE, Workspace

MAP_NAMES = ("vlmap", "cfmap")
_BUILD_STAGE = {"frames": "ingest", "recon": "reconstruct", "vlmap": "vlmap", "cfmap": "cfmap", "goals": "goals",
                "routes": "routes"}
READ_STAGES = tuple(dict.fromkeys(_BUILD_STAGE.values()))  # the stages whose artifacts a Scene reads
_PRODUCER = {**_BUILD_STAGE, "raw_log": "simulate", "recon_mesh": "reconstruct", "recon_points": "reconstruct"}


def open(source: str | Path = ".", *, data_dir: str | Path | None = None, manifests_dir: str | Path | None = None,
         overrides: Sequence[str] = ()) -> "Dataset":
    """Open a zipon dataset.

    ``source`` is a ``params.yaml``, a project folder holding one, or a data root (a folder with
    ``artifacts/<scene>/``; its params are the ``params.yaml`` beside it when there is one, else the
    defaults). ``overrides`` are ``KEY=VALUE`` strings as for ``zipon -S``.

    ``data_dir`` may be an object store (``s3://bucket/prefix``, :mod:`pipeline.fsroot`): the published version of
    an artifact is then brought into the local mirror (:func:`pipeline.paths.cache_dir`) when it is first asked for
    (:meth:`Scene.path`; :meth:`Dataset.mirror` brings whole scenes), and read there.
    """
    from pipeline.paramsfile import load_params, parse_params

    path = Path(source).expanduser()
    if path.is_file():
        params_path = path
    elif (path / PARAMS_FILE).is_file():
        params_path = path / PARAMS_FILE
    elif (path / "artifacts").is_dir():
        beside = path.resolve().parent / PARAMS_FILE
        ws = Workspace(root=path.resolve().parent, data_dir=Path(data_dir or path).resolve(),
                       manifests_dir=Path(manifests_dir or path.resolve().parent / "manifests").resolve())
        params = load_params(beside, overrides) if beside.is_file() else parse_params(
            {"scenes": {}}, origin=f"defaults for {path}", overrides=overrides)
        return Dataset(ws, params)
    else:
        raise MissingInputError(f"{path}: neither a params file, a folder with {PARAMS_FILE}, nor a data root "
                                f"(a folder with artifacts/<scene>/)")
    ws = Workspace.resolve(params_path, data_dir, manifests_dir)
    return Dataset(ws, load_params(ws.params_path, overrides))


class Dataset:
    """The scenes of one workspace: ``ds["sim_00"]``, ``list(ds)`` (names), ``ds.scenes`` (Scene objects)."""

    def __init__(self, workspace: Workspace, params):
        self.workspace, self.params = workspace, params
        self._scenes: dict[str, Scene] = {}
        self._mirrored: set[tuple[str, str]] = set()  # (scene, stage) pairs mirrored from an object store

    @property
    def names(self) -> list[str]:
        """Scenes in params order, then any other scene folder under ``artifacts/`` (and, on an object store, any
        other scene with a published manifest)."""
        names = list(self.params.scenes)
        root = self.workspace.data_dir / "artifacts"
        if root.is_dir():
            names += sorted(p.name for p in root.iterdir() if p.is_dir() and p.name not in names
                            and not p.name.startswith("."))
        return names + [n for n in self._published if n not in names]

    @cached_property
    def _published(self) -> list[str]:
        """Scenes with a published manifest on the object-store data root (none for a local root)."""
        if self.workspace.remote is None:
            return []
        from pipeline.fsroot import RemoteRoot

        return RemoteRoot(self.workspace.remote).scenes()

    def mirror(self, scenes: Sequence[str] | None = None, stages: Sequence[str] = READ_STAGES) -> None:
        """On an object-store data root: bring the published versions of ``stages`` (default: every stage a Scene
        reads) of ``scenes`` (default: all) into the local mirror, where this dataset reads them
        (:func:`pipeline.fsroot.pull_stages`: only versions not mirrored yet are downloaded, each digest-checked; a
        stage never published stays absent). Each (scene, stage) is mirrored once per Dataset; nothing happens on a
        local data root."""
        if self.workspace.remote is None:
            return
        todo = [(scene, stage) for scene in dict.fromkeys(self.names if scenes is None else scenes)
                for stage in stages if (scene, stage) not in self._mirrored]
        if todo:
            from pipeline.fsroot import pull_stages

            pull_stages(self.workspace, todo)
            self._mirrored.update(todo)

    @property
    def scenes(self) -> list["Scene"]:
        return [self[n] for n in self.names]

    def __getitem__(self, name: str) -> "Scene":
        if name not in self._scenes:
            if name not in self.names:
                raise ConfigError(f"unknown scene {name!r}: {self.workspace.params_path} lists "
                                  f"{sorted(self.params.scenes)} and {self.workspace.data_dir / 'artifacts'} holds "
                                  f"{[n for n in self.names if n not in self.params.scenes]}")
            self._scenes[name] = Scene(self, name)
        return self._scenes[name]

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        return f"Dataset({str(self.workspace.data_dir)!r}, scenes={self.names})"

    def run_eval(self, out_dir: str | Path, **kwargs) -> dict:
        """:func:`zipon.run_eval` on this dataset."""
        from zipon.evaluate import run_eval

        self.mirror(kwargs.get("scenes") or self.params.eval.scenes or list(self.params.scenes))  # what it evaluates
        return run_eval(self.workspace, self.params, out_dir, **kwargs)


class Scene:
    """One scene's artifacts, opened on first access (each a store reader; see the module docstring)."""

    def __init__(self, dataset: Dataset, name: str):
        self.dataset, self.name = dataset, name

    def __repr__(self) -> str:
        have = [a for a in _BUILD_STAGE if self.dataset.workspace.artifact(a, self.name).exists()]  # no download
        return f"Scene({self.name!r}, artifacts={have})"

    def path(self, artifact: str) -> Path:
        """Where ``artifact`` ('frames', 'recon', 'vlmap', ...) of this scene lives (it may not exist yet). On an
        object-store data root the published version of its stage is brought into the local mirror first."""
        if artifact in _PRODUCER:
            self.dataset.mirror([self.name], [_PRODUCER[artifact]])
        return self.dataset.workspace.artifact(artifact, self.name)

    def _existing(self, artifact: str) -> Path:
        p = self.path(artifact)
        if not p.exists():
            raise MissingInputError(f"{p}: scene {self.name!r} has no {artifact} yet "
                                    f"(build it: zipon run -s {self.name} --stage {_BUILD_STAGE[artifact]})")
        return p

    @cached_property
    def frames(self):
        """:class:`~pipeline.frames.FrameStore`: rgb, depth (mm), pose (T_world_camera), stamp (ns)."""
        from pipeline.frames import FrameStore

        return FrameStore(self._existing("frames"))

    @cached_property
    def recon(self):
        """:class:`~pipeline.recon.Recon`: occupancy, navigable, color, height grids; ``mesh_path``."""
        from pipeline.recon import Recon

        return Recon(self._existing("recon"))

    @cached_property
    def vlmap(self) -> "MapView":
        return MapView(self, "vlmap")

    @cached_property
    def cfmap(self) -> "MapView":
        return MapView(self, "cfmap")

    @cached_property
    def goals(self):
        """:class:`~pipeline.goals.store.Goals`: ``.goals`` (GoalView list), ``.objects``, ``.document``."""
        from pipeline.goals.store import Goals

        return Goals(self._existing("goals"))

    @cached_property
    def routes(self):
        """:class:`~pipeline.routes.store.Routes`: verified episodes with geodesic paths and actions."""
        from pipeline.routes.store import Routes

        return Routes(self._existing("routes"))

    @property
    def episodes(self) -> list:
        """The routes' episodes (:class:`~pipeline.routes.store.EpisodeView`: id, goal_id, start, path_xy, ...)."""
        return self.routes.episodes

    def map(self, which: str) -> "MapView":
        if which not in MAP_NAMES:
            raise ConfigError(f"map {which!r}: choose one of {list(MAP_NAMES)}")
        return getattr(self, which)


class MapView:
    """A semantic map of a scene: text queries, the dense xarray grid, features at world points."""

    def __init__(self, scene: Scene, which: str):
        self.scene, self.which = scene, which
        self.path = scene._existing(which)

    def __repr__(self) -> str:
        s = self.store
        return f"MapView({self.scene.name!r}, {self.which!r}, encoder={s.encoder.get('name')!r}, cells={s.n_cells})"

    @cached_property
    def store(self):
        """The :class:`~pipeline.maps.store.SemanticMap` reader."""
        from pipeline.maps.store import SemanticMap

        return SemanticMap(self.path)

    @property
    def grid(self):
        return self.store.grid

    @property
    def encoder(self) -> dict:
        return dict(self.store.encoder)

    def _query(self):
        from pipeline.maps.query import open_query

        sc = self.scene
        recon = sc.path("recon")
        return open_query(self.path, sc.dataset.params, recon_path=recon if recon.exists() else None,
                          frames_path=sc.path("frames"))

    def query(self, text: str, pose: Sequence[float] | None = None):
        """Heatmap and object candidates for ``text`` (:class:`~pipeline.maps.query.QueryResult`).

        ``pose`` = (x, y, yaw): world metres and radians (counter-clockwise from +x); candidates are then
        sorted by distance and carry ``distance_m`` / ``angle_rad`` from it. A pose off the map's grid is
        an :class:`~pipeline.errors.InputDataError`.
        """
        if pose is not None:
            pose = check_pose(self.grid, pose, field="pose")
        return self._query().query(text, pose)

    def features_at(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """Features ``(K,D)`` float32 at world points ``xy`` ``(K,2)`` metres and a ``(K,)`` bool observed mask
        (rows of unobserved or off-grid points are zeros)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return self.store.features_at(self.grid.world_to_cell(xy))

    def to_xarray(self):
        """The map as an ``xarray.Dataset`` on its dense grid (see :func:`map_to_xarray`)."""
        return map_to_xarray(self.store)


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


def map_to_xarray(smap):
    """A :class:`~pipeline.maps.store.SemanticMap` as ``xarray.Dataset`` on dims ``(y, x[, feature])``.

    ``features`` ``(y, x, feature)`` float16 is a lazy dask array gathered tile by tile from the stored
    compact rows (NaN where unobserved), so a 600x600x512 map costs nothing until sliced; ``observed``,
    ``weight``, ``count`` and ``top_z`` (world z of the cell's top level, metres) are ``(y, x)``.
    Coordinates ``x``, ``y`` are world metres of the cell centres; units are in each variable's attrs.
    """
    import dask.array as da
    import xarray as xr

    g = smap.grid
    index = smap.index
    ok = index >= 0
    rows = index[ok]
    feats = smap.features16()
    dim = feats.shape[1]
    tile = smap.tile_cells

    def gather(block: np.ndarray) -> np.ndarray:
        out = np.full(block.shape + (dim,), np.nan, np.float16)
        m = block >= 0
        out[m] = feats[block[m]]
        return out

    lazy_index = da.from_array(index, chunks=(tile, tile), name=f"zipon-index-{smap.path}")
    features = lazy_index.map_blocks(gather, new_axis=2, chunks=lazy_index.chunks + ((dim,),), dtype=np.float16,
                                     name=f"zipon-features-{smap.path}")

    def dense(values: np.ndarray, fill, dtype) -> np.ndarray:
        out = np.full(index.shape, fill, dtype)
        out[ok] = values[rows]
        return out

    top_z = smap.lattice.level_z(smap.level)
    enc = {k: v for k, v in smap.encoder.items() if isinstance(v, (str, int, float, bool))}
    coords = grid_coords(g)
    ds = xr.Dataset(
        {
            "features": (("y", "x", "feature"), features,
                         {"units": "1", "long_name": f"unit L2-norm {enc.get('name')} feature, NaN = unobserved"}),
            "observed": (("y", "x"), ok, {"units": "1", "long_name": "cell has a feature"}),
            "weight": (("y", "x"), dense(smap.weight.astype(np.float32), np.nan, np.float32),
                       {"units": "1", "long_name": "sum of point weights fused into the cell"}),
            "count": (("y", "x"), dense(smap.count.astype(np.int32), -1, np.int32),
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


def run_eval(dataset, out_dir: str | Path = "eval_out", **kwargs) -> dict:
    """Evaluate agents on built scenes; writes ``out_dir/results.json`` (+ report.html) and returns the results.

    ``dataset``: a :class:`Dataset` or anything :func:`open` takes; the keywords (``agents``, ``scenes``,
    ``feedback``, ``seeds``, ``report``, ``progress``) are :func:`zipon.evaluate.run_eval`'s.
    """
    ds = dataset if isinstance(dataset, Dataset) else open(dataset)
    return ds.run_eval(out_dir, **kwargs)
