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
        .<stage>.lock                  held while a run builds that stage (pipeline.locks)
        .<stage>.publish.json          publication journal, present only while one is in flight
    manifests/<scene>/<stage>.json     committed provenance (``--manifests-dir``)

The same templates are saved into every manifest so a dataset documents its own layout.
"""

from __future__ import annotations

import os
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
MANIFEST = "{scene}/{stage}.json"

ENV_DATA = "ZIPON_DATA"
ENV_MANIFESTS = "ZIPON_MANIFESTS"
PARAMS_FILE = "params.yaml"


@dataclass(frozen=True)
class Workspace:
    """Where params, data and manifests live for one run."""

    root: Path
    data_dir: Path
    manifests_dir: Path
    params_file: Path | None = None  # the params file itself (any name); None = root / params.yaml

    @classmethod
    def resolve(
        cls,
        params_path: str | Path | None = None,
        data_dir: str | Path | None = None,
        manifests_dir: str | Path | None = None,
    ) -> "Workspace":
        """Explicit arguments win over ``ZIPON_DATA`` / ``ZIPON_MANIFESTS``, which win over defaults."""
        params = (Path(params_path) if params_path else Path.cwd() / PARAMS_FILE).resolve()
        root = params.parent
        data = data_dir or os.environ.get(ENV_DATA) or root / "data"
        manifests = manifests_dir or os.environ.get(ENV_MANIFESTS) or root / "manifests"
        return cls(root=root, data_dir=Path(data).resolve(), manifests_dir=Path(manifests).resolve(),
                   params_file=params)

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

    def renders(self, scene: str) -> Path:
        return self.data_dir / RENDERS.format(scene=scene)

    def tmp_dir(self, scene: str) -> Path:
        return self.data_dir / TMP.format(scene=scene)

    def lock(self, scene: str, stage: str) -> Path:
        return self.data_dir / LOCK.format(scene=scene, stage=stage)

    def journal(self, scene: str, stage: str) -> Path:
        return self.data_dir / JOURNAL.format(scene=scene, stage=stage)

    def relative(self, path: Path) -> str:
        """A path as recorded in manifests: relative to the data root when inside it."""
        path = Path(path).resolve()
        for base, prefix in ((self.data_dir, "data"), (self.root, ".")):
            try:
                return f"{prefix}/{path.relative_to(base).as_posix()}"
            except ValueError:
                continue
        return path.as_posix()
