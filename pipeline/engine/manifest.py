"""Manifests: ``manifests/<scene>/<stage>.json``, the provenance of one stage's outputs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.errors import ArtifactError

MANIFEST_FORMAT_VERSION = 1
MAX_MANIFEST_BYTES = 16 << 20  # a manifest lists a stage's code files and figures: tens of kB


class OutputRecord(BaseModel):
    model_config = ConfigDict(extra="forbid")
    path: str = Field(description="as recorded: relative to the data root ('data/...') when inside it")
    digest: str = Field(description="deterministic content digest (decoded zarr content or file bytes)")


class Manifest(BaseModel):
    """What produced an artifact, from what, with which params; and what it holds."""

    model_config = ConfigDict(extra="forbid")
    format_version: int = MANIFEST_FORMAT_VERSION
    stage: str
    scene: str
    code_version: str
    code_digest: str
    code_files: dict[str, str] = Field(
        default_factory=dict, description="source file (relative to the project) -> digest, for every file of the "
        "stage's import closure (pipeline.engine.codedeps); names what changed when code_digest differs")
    params: dict[str, Any] = Field(description="the stage's config as params keys -> values (exactly what "
                                   "params_digest covers)")
    params_digest: str
    inputs: dict[str, str] = Field(description="input name -> digest (upstream output digest or raw files digest)")
    outputs: dict[str, OutputRecord]
    summary: dict[str, Any] = Field(default_factory=dict, description="the stage's figures")
    timing: dict[str, Any] = Field(default_factory=dict, description="started (UTC ISO), seconds (wall), "
                                   "cpu_seconds (process CPU time of the stage), peak_rss_mb (the worker process's "
                                   "peak resident memory up to the end of the stage), waited_seconds, native_threads "
                                   "(the BLAS/torch/open3d threads it ran with), counters (the worker process's page faults, "
                                   "context switches and bytes read over the stage: pipeline.engine.process.process_counters),"
                                   " host, python")
    layout: dict[str, str] = Field(default_factory=dict, description="artifact path templates of this zipon")

    def text(self) -> str:
        """The file's exact text (a publication journal carries it, see :mod:`pipeline.engine.publication`)."""
        return json.dumps(self.model_dump(mode="json"), indent=2, sort_keys=True) + "\n"

    def write(self, path: Path) -> None:
        from pipeline.store import write_text_atomic  # here: reading a manifest (`zipon status`) needs no numpy

        write_text_atomic(path, self.text())

    @classmethod
    def read(cls, path: Path) -> "Manifest | None":
        """The manifest at ``path``, or ``None`` when there is none. Read back as user input: a file that is not
        UTF-8 JSON, is over :data:`MAX_MANIFEST_BYTES`, or does not validate is an :class:`ArtifactError` naming it
        (where the first problem is)."""
        path = Path(path)
        if not path.is_file():
            return None
        with open(path, "rb") as f:
            data = f.read(MAX_MANIFEST_BYTES + 1)
        if len(data) > MAX_MANIFEST_BYTES:
            raise ArtifactError(f"{path}: not a valid zipon manifest: over {MAX_MANIFEST_BYTES:,} bytes")
        try:
            return cls.model_validate_json(data)
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise ArtifactError(f"{path}: not a valid zipon manifest: {where + ': ' if where else ''}"
                                f"{first['msg']}") from None
