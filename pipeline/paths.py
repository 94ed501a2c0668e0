"""Every artifact path, built in one place.

Layout under the data root (``--data-dir`` / ``ZIPON_DATA``, default ``<workspace>/data``)::

    data/
      raw/<scene>.mcap                 simulated ROS 2 logs (stage ``simulate``)
      artifacts/<scene>/
        frames.zarr                    stage ``ingest``
        recon.zarr, recon_mesh.ply     stage ``reconstruct`` (+ recon_points.ply)
        vlmap.zarr / cfmap.zarr        stages ``vlmap`` / ``cfmap``
        goals.zarr / routes.zarr       stages ``goals`` / ``routes``
        renders/                       PNG pictures (not artifacts; never hashed)
        .tmp/                          stage outputs being written (removed on success)
        .<stage>.lock                  held while a run builds that stage (pipeline.engine.locks)
        .<stage>.publish.json          publication journal, present only while one is in flight
        .<stage>.fold/                 vlmap/cfmap: fold of the complete frame chunks (a cache; pipeline.maps.incremental)
    manifests/<scene>/<stage>.json     committed provenance (``--manifests-dir``)

Beside the params file, committed with it (a dataset project, :mod:`pipeline.project`)::

    .zipon/code/<stage>.json           the stage's code identity: zipon's version and the stage's code digest
                                       (what ``dvc.yaml`` lists as the stage's code, :mod:`pipeline.engine.dvcfile`)
    DATASET.md, dataset.json           the dataset card of this version and its machine-readable twin

The same templates are saved into every manifest so a dataset documents its own layout. A data root given as a
URL (``s3://bucket/prefix``) is an object store: the layout above is then a local cache of it (:func:`cache_dir`)
and the store holds published versions (``<path>@<digest>``) and the manifests (:mod:`pipeline.engine.fsroot`).
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

# Artifact name -> path template relative to the data root.
ARTIFACTS: dict[str, str] = {
    "raw_log": "raw/{scene}.mcap",
    "frames": "artifacts/{scene}/frames.zarr",
    "recon": "artifacts/{scene}/recon.zarr",
    "recon_mesh": "artifacts/{scene}/recon_mesh.ply",
    "recon_points": "artifacts/{scene}/recon_points.ply",
    "vlmap": "artifacts/{scene}/vlmap.zarr",
    "cfmap": "artifacts/{scene}/cfmap.zarr",
    "goals": "artifacts/{scene}/goals.zarr",
    "routes": "artifacts/{scene}/routes.zarr",
}
RENDERS = "artifacts/{scene}/renders"
TMP = "artifacts/{scene}/.tmp"
LOCK = "artifacts/{scene}/.{stage}.lock"
JOURNAL = "artifacts/{scene}/.{stage}.publish.json"
FOLD = "artifacts/{scene}/.{stage}.fold"
MANIFEST = "{scene}/{stage}.json"
# relative to the workspace root (the params file's folder)
CODE_ID = ".zipon/code/{stage}.json"
CARD_MD = "DATASET.md"
CARD_JSON = "dataset.json"

ENV_DATA = "ZIPON_DATA"
ENV_MANIFESTS = "ZIPON_MANIFESTS"
ENV_CACHE = "ZIPON_CACHE"
PARAMS_FILE = "params.yaml"

URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]+://")


def is_url(value: str | Path) -> bool:
    """Whether a data root names an fsspec filesystem (``s3://bucket/prefix``, ``memory://x``) rather than a folder."""
    return bool(URL.match(str(value)))


def check_url(url: str) -> None:
    """An object-store URL names its bucket (``s3://BUCKET[/PREFIX]``): ``s3://`` alone is refused, not taken as a
    local folder or the store's root."""
    from urllib.parse import urlsplit

    from pipeline.errors import ConfigError

    parts = urlsplit(url)
    if parts.scheme not in ("file", "memory") and not parts.netloc:
        raise ConfigError(f"--data-dir {url}: no bucket named (expected {parts.scheme}://BUCKET or "
                          f"{parts.scheme}://BUCKET/PREFIX)")


def cache_dir(url: str, workspace_root: Path) -> Path:
    """The local mirror of the data root ``url`` (:mod:`pipeline.engine.fsroot`): ``$ZIPON_CACHE/<url>`` or
    ``<workspace>/.zipon-cache/<url>``, the URL made a folder name plus a short hash so two URLs never share one."""
    base = Path(os.environ.get(ENV_CACHE) or Path(workspace_root) / ".zipon-cache")
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", url.rstrip("/")).strip("_")
    return (base / f"{name}-{hashlib.blake2b(url.rstrip('/').encode(), digest_size=4).hexdigest()}").resolve()


@dataclass(frozen=True)
class Workspace:
    """Where params, data and manifests live for one run."""

    root: Path
    data_dir: Path
    manifests_dir: Path
    params_file: Path | None = None  # the params file itself (any name); None = root / params.yaml
    # the data root when it is an object-store URL (s3://bucket/prefix); data_dir is then its local cache
    # (pipeline.engine.fsroot) and manifests_dir defaults to the cache's manifests/
    remote: str | None = None

    @classmethod
    def resolve(
        cls,
        params_path: str | Path | None = None,
        data_dir: str | Path | None = None,
        manifests_dir: str | Path | None = None,
    ) -> "Workspace":
        """Explicit arguments win over ``ZIPON_DATA`` / ``ZIPON_MANIFESTS``, which win over defaults.

        A data root given as a URL (``s3://bucket/prefix``; see :func:`is_url`) is an object store: ``data_dir`` is
        then its local cache (:func:`cache_dir`) and ``remote`` the URL.
        """
        params = (Path(params_path) if params_path else Path.cwd() / PARAMS_FILE).resolve()
        root = params.parent
        data = data_dir or os.environ.get(ENV_DATA) or root / "data"
        remote = None
        if is_url(data):
            check_url(str(data))
            remote, data = str(data).rstrip("/"), cache_dir(str(data), root)
        manifests = manifests_dir or os.environ.get(ENV_MANIFESTS) or (
            Path(data) / "manifests" if remote else root / "manifests")
        for given, env, option, path in ((data_dir, ENV_DATA, "--data-dir", data),
                                         (manifests_dir, ENV_MANIFESTS, "--manifests-dir", manifests)):
            if Path(path).exists() and not Path(path).is_dir():
                from pipeline.errors import ConfigError

                how = option if given else env if os.environ.get(env) else f"{option} (default)"
                raise ConfigError(f"{how} {path}: is a file, not a folder; point {option} at a folder")
        return cls(root=root, data_dir=Path(data).resolve(), manifests_dir=Path(manifests).resolve(),
                   params_file=params, remote=remote)

    @property
    def params_path(self) -> Path:
        """The params file given (``--params FILE`` is read whatever its name), else ``root/params.yaml``."""
        return self.params_file or self.root / PARAMS_FILE

    def artifact(self, name: str, scene: str) -> Path:
        try:
            template = ARTIFACTS[name]
        except KeyError:
            raise KeyError(f"unknown artifact {name!r}; known: {sorted(ARTIFACTS)}") from None
        return self.data_dir / template.format(scene=scene)

    def manifest(self, scene: str, stage: str) -> Path:
        return self.manifests_dir / MANIFEST.format(scene=scene, stage=stage)

    def code_id(self, stage: str) -> Path:
        """The stage's code identity file (:mod:`pipeline.engine.dvcfile`), beside the params file."""
        return self.root / CODE_ID.format(stage=stage)

    def renders(self, scene: str) -> Path:
        return self.data_dir / RENDERS.format(scene=scene)

    def tmp_dir(self, scene: str) -> Path:
        return self.data_dir / TMP.format(scene=scene)

    def lock(self, scene: str, stage: str) -> Path:
        return self.data_dir / LOCK.format(scene=scene, stage=stage)

    def journal(self, scene: str, stage: str) -> Path:
        return self.data_dir / JOURNAL.format(scene=scene, stage=stage)

    def fold(self, scene: str, stage: str) -> Path:
        """A map stage's fold cache (:mod:`pipeline.maps.incremental`)."""
        return self.data_dir / FOLD.format(scene=scene, stage=stage)

    def relative(self, path: Path) -> str:
        """A path as recorded in manifests: relative to the data root when inside it."""
        path = Path(path).resolve()
        for base, prefix in ((self.data_dir, "data"), (self.root, ".")):
            try:
                return f"{prefix}/{path.relative_to(base).as_posix()}"
            except ValueError:
                continue
        return path.as_posix()
