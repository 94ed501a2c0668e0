"""``zipon.open`` -> :class:`Dataset` -> :class:`Scene` -> artifacts and :class:`MapView` (the scene handle and
map view are the library's, :mod:`pipeline.scene`, re-exported here).

Nothing here re-implements a reader: scenes hand out the stores' own readers
(:class:`~pipeline.frames.FrameStore`, :class:`~pipeline.recon.Recon`, :class:`~pipeline.goals.store.Goals`,
:class:`~pipeline.routes.store.Routes`) and maps query through :func:`pipeline.maps.query.open_query`
(cached, so repeated queries cost one product). Units are the project's: metres, radians, world z up.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Iterator, Sequence

from pipeline.errors import ConfigError, MissingInputError
from pipeline.paths import PARAMS_FILE, Workspace
from pipeline.scene import MAP_NAMES, MapView, Scene, check_pose, grid_coords, map_to_xarray, read_stages
from stages import STAGES

__all__ = ["MAP_NAMES", "Dataset", "MapView", "Scene", "check_pose", "grid_coords", "map_to_xarray", "open"]


def open(source: str | Path = ".", *, data_dir: str | Path | None = None, manifests_dir: str | Path | None = None,
         overrides: Sequence[str] = ()) -> "Dataset":
    """Open a zipon dataset.

    ``source`` is a ``params.yaml``, a project folder holding one, or a data root (a folder with
    ``artifacts/<scene>/``; its params are the ``params.yaml`` beside it when there is one, else the
    defaults). ``overrides`` are ``KEY=VALUE`` strings as for ``zipon -S``.

    ``data_dir`` may be an object store (``s3://bucket/prefix``, :mod:`pipeline.engine.fsroot`): the published version of
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
        from pipeline.engine.fsroot import RemoteRoot

        return RemoteRoot(self.workspace.remote).scenes()

    def mirror(self, scenes: Sequence[str] | None = None, stages: Sequence[str] | None = None) -> None:
        """On an object-store data root: bring the published versions of ``stages`` (default: every stage a Scene
        reads) of ``scenes`` (default: all) into the local mirror, where this dataset reads them
        (:func:`pipeline.engine.fsroot.pull_stages`: only versions not mirrored yet are downloaded, each digest-checked; a
        stage never published stays absent). Each (scene, stage) is mirrored once per Dataset; nothing happens on a
        local data root."""
        if self.workspace.remote is None:
            return
        todo = [(scene, stage) for scene in dict.fromkeys(self.names if scenes is None else scenes)
                for stage in (read_stages(STAGES) if stages is None else stages) if (scene, stage) not in self._mirrored]
        if todo:
            from pipeline.engine.fsroot import pull_stages

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
            self._scenes[name] = Scene(self.workspace, self.params, name, STAGES,
                                       fetch=lambda stage: self.mirror([name], [stage]))
        return self._scenes[name]

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        return f"Dataset({str(self.workspace.data_dir)!r}, scenes={self.names})"
