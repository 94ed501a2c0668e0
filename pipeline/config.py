"""Typed configuration: ``params.yaml`` validated at load, one section per stage.

Every tunable lives here, documented once. A stage reads only its own section(s) (its
``StageSpec.params``), and the digest of exactly those sections decides whether it is stale.
Errors name the key: ``params.yaml: ingest.block_frames: Input should be greater than 0``.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from pipeline.errors import ConfigError


class Section(BaseModel):
    """Base of every params section: unknown keys are errors, values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# ----------------------------------------------------------------------------- scenes

SceneFormat = Literal["auto", "mcap", "tum", "7scenes", "navchat"]


class SceneSource(Section):
    """Where one scene's raw data comes from."""

    source: str = Field(
        description="'simulate' for an embedded procedural scene (raw log written by the simulate stage), "
        "or a path (relative to the params file) to a raw log / dataset folder"
    )
    format: SceneFormat = Field("auto", description="reader to use; 'auto' detects it from the path")

    @property
    def simulated(self) -> bool:
        return self.source == "simulate"


# ----------------------------------------------------------------------------- stages

class SimulateParams(Section):
    """Procedural indoor scenes rendered to ROS 2 MCAP logs (the embedded default data)."""

    seed: int = Field(0, description="base seed; each scene's seed is derived from it and the scene name")
    frames: int = Field(240, gt=0, description="frames recorded per scene")
    width: int = Field(640, gt=0, description="image width, pixels")
    height: int = Field(480, gt=0, description="image height, pixels")
    hfov_deg: float = Field(90.0, gt=0, lt=180, description="horizontal field of view, degrees")
    camera_height_m: float = Field(0.88, gt=0, description="camera height above the floor, metres")
    depth_min_m: float = Field(0.1, ge=0, description="nearest valid depth, metres")
    depth_max_m: float = Field(10.0, gt=0, description="farthest valid depth, metres")
    fps: float = Field(10.0, gt=0, description="frame rate of the recorded camera streams, Hz")
    pose_rate_hz: float = Field(30.0, gt=0, description="rate of the pose / tf streams, Hz")
    depth_noise_m: float = Field(0.0, ge=0, description="std of depth noise at 1 m (grows with depth^2), metres")
    pose_jitter_m: float = Field(0.0, ge=0, description="std of recorded-position noise, metres")
    pose_jitter_deg: float = Field(0.0, ge=0, description="std of recorded-heading noise, degrees")
    image_transport: Literal["raw", "compressed"] = Field(
        "raw", description="raw sensor_msgs/Image, or sensor_msgs/CompressedImage (png colour and depth)"
    )
    pose_topic_kind: Literal["pose", "tf", "both"] = Field(
        "both", description="write camera poses as geometry_msgs/PoseStamped, /tf, or both"
    )


class IngestTopics(Section):
    """ROS 2 topic names; ``None`` means auto-detect from the message types in the log."""

    rgb: str | None = None
    depth: str | None = None
    camera_info: str | None = None
    pose: str | None = Field(None, description="a geometry_msgs/PoseStamped topic of the camera pose")
    tf_world_frame: str | None = Field(None, description="/tf parent frame to chain from (auto: the root)")
    tf_camera_frame: str | None = Field(None, description="/tf child frame of the optical camera (auto)")


class IngestParams(Section):
    """Raw logs / dataset folders -> ``frames.zarr``."""

    block_frames: int = Field(16, gt=0, description="frames per zarr chunk and per processing block")
    max_rgb_depth_dt_s: float = Field(0.02, ge=0, description="colour/depth stamps match within this, seconds")
    max_pose_gap_s: float = Field(
        0.1, gt=0, description="a pose is interpolated only between samples at most this far apart, seconds"
    )
    max_pose_extrapolation_s: float = Field(
        0.0, ge=0, description="a frame this close before the first / after the last pose takes that pose"
    )
    depth_min_m: float = Field(0.1, ge=0, description="depth below this is stored as invalid (0)")
    depth_max_m: float = Field(10.0, gt=0, description="depth above this is stored as invalid (0)")
    compression_level: int = Field(3, ge=1, le=9, description="zstd level of the blosc compressor")
    topics: IngestTopics = IngestTopics()
    navchat_camera_height_m: float = Field(0.88, gt=0, description="camera height above navchat's base pose")
    folder_fps: float = Field(
        30.0, gt=0, description="frame rate assumed for datasets without timestamps (7-Scenes, navchat)"
    )


class GridParams(Section):
    """The top-down grid every map, route and evaluator reads (DESIGN.md)."""

    rows: int = Field(600, gt=0, description="grid rows (north-south)")
    cols: int = Field(600, gt=0, description="grid columns (west-east)")
    cell_size_m: float = Field(0.05, gt=0, description="cell edge, metres")


class ReconstructParams(Section):
    """Frames -> fused geometry (TSDF) and the top-down grids (``recon.zarr``)."""


class EncodersParams(Section):
    """Open-vocabulary pixel/text encoders used by the map stages and the evaluator."""


class GoalsParams(Section):
    """Objects -> personalized goals with the four kinds of feedback (``goals.zarr``)."""


class RoutesParams(Section):
    """Goals + navigable grid -> episodes, geodesic routes and procedural text (``routes.zarr``)."""


class RunParams(Section):
    """How ``zipon run`` schedules work."""

    scheduler: str = Field(
        "sync",
        description="'sync' (one process), 'threads', 'processes', or a dask.distributed scheduler "
        "address such as tcp://10.0.0.5:8786",
    )
    workers: int = Field(2, gt=0, description="local workers for 'threads' / 'processes'")
    threads_per_worker: int = Field(1, gt=0, description="native threads (BLAS/torch/open3d) inside a worker")


class Params(Section):
    """The whole ``params.yaml``."""

    scenes: dict[str, SceneSource] = Field(description="scene name -> raw source; 'zipon run' builds all of them")
    run: RunParams = RunParams()
    grid: GridParams = GridParams()
    simulate: SimulateParams = SimulateParams()
    ingest: IngestParams = IngestParams()
    reconstruct: ReconstructParams = ReconstructParams()
    encoders: EncodersParams = EncodersParams()
    goals: GoalsParams = GoalsParams()
    routes: RoutesParams = RoutesParams()

    @field_validator("scenes")
    @classmethod
    def _scene_names(cls, scenes: dict[str, SceneSource]) -> dict[str, SceneSource]:
        for name in scenes:
            if not name or any(ch in name for ch in "/\\ .") or name.startswith("-"):
                raise ValueError(f"scene name {name!r} must be a plain identifier (letters, digits, _ -)")
        return scenes

    @model_validator(mode="after")
    def _depth_ranges(self) -> "Params":
        for key in ("simulate", "ingest"):
            sec = getattr(self, key)
            if sec.depth_min_m >= sec.depth_max_m:
                raise ValueError(f"{key}.depth_min_m must be below {key}.depth_max_m")
        return self

    def section(self, dotted: str) -> Any:
        obj: Any = self
        for part in dotted.split("."):
            obj = obj[part] if isinstance(obj, dict) else getattr(obj, part)
        return obj

    def section_dump(self, dotted: str) -> Any:
        value = self.section(dotted)
        return value.model_dump(mode="json") if isinstance(value, BaseModel) else value


# ----------------------------------------------------------------------------- load

def _apply_override(raw: dict, assignment: str) -> None:
    if "=" not in assignment:
        raise ConfigError(f"override {assignment!r}: expected KEY=VALUE, e.g. simulate.frames=100")
    key, value = assignment.split("=", 1)
    parts = key.strip().split(".")
    node = raw
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"override {assignment!r}: {part!r} is not a section")
    node[parts[-1]] = yaml.safe_load(value)


def _format_errors(err: ValidationError, origin: str) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(top level)"
        lines.append(f"{origin}: {loc}: {e['msg']}")
    return "\n".join(lines)


def parse_params(raw: dict, *, origin: str = "params", overrides: list[str] | tuple[str, ...] = ()) -> Params:
    """Validate a params mapping (after ``KEY=VALUE`` overrides); raises :class:`ConfigError`."""
    raw = json.loads(json.dumps(raw or {}))  # deep copy of plain data
    for assignment in overrides:
        _apply_override(raw, assignment)
    try:
        return Params.model_validate(raw)
    except ValidationError as err:
        raise ConfigError(_format_errors(err, origin)) from None


def load_params(path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> Params:
    """Read and validate ``params.yaml``."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: params file not found (run zipon from the project folder or pass --params)")
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML: {err}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level")
    return parse_params(raw, origin=str(path), overrides=overrides)


def canonical_json(value: Any) -> str:
    """The JSON text digests are computed on: sorted keys, no whitespace, finite floats."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def digest_value(value: Any) -> str:
    """Deterministic digest of plain data (params sections, attrs)."""
    return "blake2b:" + hashlib.blake2b(canonical_json(value).encode(), digest_size=16).hexdigest()
