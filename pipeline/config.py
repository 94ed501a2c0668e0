"""Typed configuration: ``params.yaml`` validated at load, one section per stage.

Every tunable lives here, documented once (the schema). A stage reads only its own section(s), and the digest of
exactly those keys decides whether it is stale (:mod:`pipeline.stageconfig`). Reading a params file, ``-S``
overrides, moved keys and writing ``params.yaml`` live in :mod:`pipeline.paramsfile`. Errors name the key:
``params.yaml: ingest.block_frames: Input should be greater than 0``.
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import Field, field_validator, model_serializer, model_validator

from pipeline.encoder_params import EncodersParams
from pipeline.eval_params import EvalParams, RoutesParams, TaskParams
from pipeline.ingest_params import IngestParams
from pipeline.maps_params import MapsParams, QueryParams
from pipeline.section import DepthRange, Section


# ----------------------------------------------------------------------------- scenes

class BuildingParams(Section):
    """What a simulated scene is (``scenes.<name>.building``; absent: an apartment): the stage ``simulate``'s
    per-scene settings."""

    kind: Literal["apartment", "house", "office"] = Field(
        "apartment", description="'apartment': one floor of simulate.rooms_min..rooms_max rooms; 'house': 'stories' "
        "floors joined by a staircase; 'office': one large floor of 'size_m'"
    )
    stories: int = Field(2, ge=2, le=3, description="floors of a house (each with its stair hall)")
    rooms_per_floor_min: int = Field(3, ge=2, le=6, description="fewest rooms per floor of a house, its hall aside")
    rooms_per_floor_max: int = Field(4, ge=2, le=6, description="most rooms per floor of a house, its hall aside")
    size_m: tuple[float, float] = Field(
        (60.0, 40.0), description="an office floor's extent along x and y, metres (each 10-200)"
    )
    room_area_m2: float = Field(90.0, ge=20, le=400, description="an office floor's area per room, m^2")

    @model_validator(mode="after")
    def _ranges(self) -> "BuildingParams":
        if self.rooms_per_floor_min > self.rooms_per_floor_max:
            raise ValueError("rooms_per_floor_min must not exceed rooms_per_floor_max")
        if not all(10.0 <= v <= 200.0 for v in self.size_m):
            raise ValueError(f"size_m must be two extents of 10-200 m, got {list(self.size_m)}")
        return self


class SceneSource(Section):
    """Where one scene's raw data comes from."""

    source: str | None = Field(
        None, description="'simulate' for an embedded procedural scene (raw log written by the simulate stage), "
        "or a path (relative to the params file) to a raw log / dataset folder"
    )
    sources: list[str] | None = Field(
        None, description="several raw logs / dataset folders of one scene, read in this order into one frames.zarr "
        "(instead of 'source'; appending a log to the list lets the map stages reuse their fold)"
    )
    format: str = Field("auto", description="reader to use: a built-in or installed reader's name (zipon ingest "
                        "--help lists them); 'auto' detects it from each path")
    building: BuildingParams | None = Field(
        None, description="a simulated scene's kind of building (house, office) and its settings; absent: an apartment"
    )

    @model_validator(mode="after")
    def _one_source_key(self) -> "SceneSource":
        if self.source is not None and self.sources is not None:
            raise ValueError("give either 'source' (one log) or 'sources' (a list of logs), not both")
        if self.source is None and self.sources is None:
            raise ValueError("needs 'source' ('simulate' or a path) or 'sources' (a list of paths)")
        if self.sources is not None and not self.sources:
            raise ValueError("'sources' is empty: list at least one raw log or dataset folder")
        if self.sources is not None and "simulate" in self.sources:
            raise ValueError("'sources' lists paths; a simulated scene is 'source: simulate'")
        if self.building is not None and self.source != "simulate":
            raise ValueError("'building' describes a simulated scene: only with 'source: simulate'")
        return self

    @field_validator("format")
    @classmethod
    def _known_format(cls, name: str) -> str:
        from pipeline import plugins

        if name == "auto" or name in plugins.BUILT_IN_READERS:  # known without reading the installed packages
            return name
        known = plugins.reader_names()
        if name not in known:
            raise ValueError(f"unknown format {name!r}: 'auto' or a reader, built-in or installed (zipon.readers "
                             f"entry points): {known}")
        return name

    @model_serializer(mode="wrap")
    def _without_unused_key(self, handler) -> dict:
        return {k: v for k, v in handler(self).items() if not (k in ("source", "sources", "building") and v is None)}

    @property
    def simulated(self) -> bool:
        return self.source == "simulate"

    @property
    def paths(self) -> list[str]:
        """The raw logs / dataset folders in reading order (``['simulate']`` for a simulated scene)."""
        return list(self.sources) if self.sources is not None else [self.source]


# ----------------------------------------------------------------------------- stages

class SimulateParams(DepthRange):
    """Procedural indoor scenes rendered to ROS 2 MCAP logs (the embedded default data)."""

    seed: int = Field(0, description="base seed; each scene's seed is derived from it and the scene name")
    frames: int = Field(240, ge=2, description="frames recorded per scene (at least 2: a walk has a start and an end)")
    width: int = Field(640, gt=0, description="image width, pixels")
    height: int = Field(480, gt=0, description="image height, pixels")
    hfov_deg: float = Field(90.0, gt=0, lt=180, description="horizontal field of view, degrees")
    camera_height_m: float = Field(0.88, gt=0, description="camera height above the floor, metres")
    fps: float = Field(10.0, gt=0, description="frame rate of the recorded camera streams, Hz")
    min_actions_per_frame: float = Field(
        2.0, gt=0, description="the walk takes at least this many actions (15 deg turns, 0.25 m steps) per recorded "
        "frame, revisiting rooms from further viewpoints: more sees more of the apartment with the same frames"
    )
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
    rooms_min: int = Field(6, ge=2, le=10, description="fewest rooms of a procedural apartment")
    rooms_max: int = Field(7, ge=2, le=10, description="most rooms of a procedural apartment")
    robot_radius_m: float = Field(
        0.18, gt=0, le=0.4, description="robot radius kept free in doorways and walkways, metres"
    )
    render_block_frames: int = Field(
        8, gt=0, description="frames ray-cast together (memory ~ 60 MB per frame at 640x480)"
    )

    @model_validator(mode="after")
    def _room_range(self) -> "SimulateParams":
        if self.rooms_min > self.rooms_max:
            raise ValueError("simulate.rooms_min must not exceed simulate.rooms_max")
        return self


class GridParams(Section):
    """The top-down grid every map, route and evaluator reads (world <-> cell: pipeline.geometry, nowhere else)."""

    rows: int = Field(600, gt=0, description="grid rows (north-south)")
    cols: int = Field(600, gt=0, description="grid columns (west-east)")
    cell_size_m: float = Field(0.05, gt=0, description="cell edge, metres")
    centre_xy: tuple[float, float] | None = Field(
        None, description="world x, y of the grid's centre, metres (snapped to the TSDF lattice); null = centred "
        "on the surface reconstruct saw. Pin it (and reconstruct.floor_z_m) so appending logs keeps the map's fold"
    )
    extent: Literal["grow", "fixed"] = Field(
        "grow", description="'grow': rows x cols when the reconstructed surface (its 0.5-99.5 percentile box plus 1 m "
        "each side) fits in it, else the smallest grid of whole 128-cell tiles (the zarr chunks) that covers it, so a "
        "floor of any size needs no hand-set rows/cols; 'fixed': exactly rows x cols (surface outside is counted, "
        "reconstruct.max_outside_fraction bounds it)"
    )

    @model_serializer(mode="wrap")
    def _without_unpinned_centre(self, handler) -> dict:
        """An unpinned centre and the default extent are left out of the section's value: digests of grids
        without them stay as they were (a grid that fits is the same under 'grow' as under the old fixed rule)."""
        return {k: v for k, v in handler(self).items()
                if not ((k == "centre_xy" and v is None) or (k == "extent" and v == "grow"))}


MIN_STOREY_M = 1.8  # floors (and camera levels) closer than this are one floor


class PinnedFloor(Section):
    """One floor of ``reconstruct.floors``, pinned by hand."""

    floor_z_m: float = Field(description="world z of the floor's walkable surface, metres")
    ceiling_z_m: float | None = Field(None, description="world z of its ceiling, metres; None = not given")
    name: str | None = Field(None, description="a name for the floor ('ground floor'); None = 'floor <id>'")

    @model_validator(mode="after")
    def _ceiling_above(self) -> "PinnedFloor":
        if self.ceiling_z_m is not None and self.ceiling_z_m <= self.floor_z_m:
            raise ValueError(f"ceiling_z_m {self.ceiling_z_m} must lie above floor_z_m {self.floor_z_m}")
        return self


class ReconstructParams(DepthRange):
    """Frames -> fused geometry (TSDF) and the top-down grids (``recon.zarr``)."""

    voxel_size_m: float = Field(
        0.025, gt=0, description="TSDF voxel edge, metres; grid.cell_size_m must be a whole multiple of it"
    )
    sdf_trunc_m: float = Field(
        0.08, gt=0, description="TSDF truncation distance, metres (keep it below the thinnest wall)"
    )
    block_resolution: int = Field(16, ge=4, le=32, description="voxels per edge of one hashed TSDF block")
    block_frames: int = Field(16, gt=0, description="frames read and fused per block")
    depth_min_m: float = Field(0.1, ge=0, description="depth below this is ignored, metres")
    depth_max_m: float = Field(5.0, gt=0, description="depth beyond this is ignored (sensor noise grows), metres")
    depth_stride: int | Literal["auto"] = Field(
        "auto", description="fuse every n-th depth pixel in each direction (1 = full resolution); 'auto' = the "
        "largest stride (at most 8) whose pixel at depth_max_m still spans no more than one voxel, i.e. "
        "stride <= voxel_size_m * focal length (px) / depth_max_m: 2 for 640x480 RGB-D cameras at the defaults, 1 "
        "for 320x240; recon.zarr records the stride used"
    )
    min_weight: float = Field(
        2.0, gt=0, description="a voxel counts as observed (mesh, points, grids) after this many fused frames"
    )
    max_invalid_frame_fraction: float = Field(
        0.5, ge=0, le=1, description="fail when more than this fraction of frames has no valid depth"
    )
    floor_z_m: float | None = Field(
        None, description="floor height in world z, metres; None = estimate it from upward-facing surfaces"
    )
    floors: list[PinnedFloor] | None = Field(
        None, description="the floors of a building pinned by hand, lowest first, at least 1.8 m apart (for "
        "buildings the rule cannot read; each must have upward-facing surface within floor_tolerance_m of its "
        "floor_z_m); None = found from the surface and the camera heights (pipeline.recon.floors)"
    )
    floor_tolerance_m: float = Field(
        0.05, gt=0, description="a cell's floor is observed when solid geometry lies within this of the floor"
    )
    obstacle_min_height_m: float = Field(
        0.1, ge=0, description="geometry above floor + this (and below obstacle_max_height_m) blocks a cell"
    )
    obstacle_max_height_m: float = Field(
        1.5, gt=0, description="top of the robot's height band above the floor, metres"
    )
    height_max_m: float = Field(
        2.0, gt=0, description="surfaces higher than this above the floor (ceilings) are left out of colour/height"
    )
    fill_enclosed_max_m2: float = Field(
        4.0, ge=0, description="unknown regions enclosed by occupied cells only and at most this big (the unseen "
        "inside of furniture) are marked occupied; bigger unknown regions get no hidden_solid inference either, m^2"
    )
    hidden_solid_max_m: float = Field(
        0.5, ge=0, description="unknown cells nearer to occupied than to free cells, and at most this far from "
        "occupied, are marked occupied (the unseen back of furniture); 0 = off, metres"
    )
    hidden_free_max_height_m: float = Field(
        0.8, ge=0, description="hidden_solid_max_m leaves a cell unknown when empty space was observed at its centre "
        "between obstacle_min_height_m and this height (a gap behind furniture seen from above); keep it below the "
        "camera height, whose view over low furniture sees the air above it, metres"
    )
    building_closing_m: float = Field(
        1.0, gt=0, description="the building's inside is the observed area closed by a disc of this radius (bridges "
        "walls hidden behind furniture); hidden_solid_max_m acts only inside it, metres"
    )
    surface_min_points: int = Field(
        3, ge=1, description="a cell is occupied by surface points (moved half a cell into the solid) only when at "
        "least this many land in it; a face passing just outside the cell centre sends one or two"
    )
    occupancy_min_weight: float = Field(
        1.0, gt=0, description="a voxel behind a surface blocks its cell (and a floor voxel marks it seen) after this "
        "many fused frames; below min_weight because thin tops seen at grazing angles are rarely updated"
    )
    robot_radius_m: float = Field(
        0.18, ge=0, description="navigable cells are free and farther than this from any occupied cell centre"
    )
    max_outside_fraction: float = Field(
        0.02, ge=0, le=1, description="fail when more than this fraction of surface points falls outside the grid"
    )
    refine_poses: bool = Field(
        False, description="refine poses by frame-to-model RGB-D odometry (real logs); refined poses are stored in "
        "recon.zarr, frames.zarr is never modified"
    )
    refine_method: Literal["hybrid", "point_to_plane"] = Field(
        "hybrid", description="odometry residual: depth + intensity ('hybrid') or depth only ('point_to_plane')"
    )
    refine_max_correction_m: float = Field(
        0.1, gt=0, description="a refinement moving a frame farther than this from its prediction is rejected, metres"
    )
    keyframes: bool = Field(
        False, description="fuse only keyframes: a frame whose camera moved or turned past the thresholds below since "
        "the last keyframe, or that sees enough pixels the last keyframe did not; every frame stays in frames.zarr "
        "and recon.zarr records which were fused (pipeline.recon.keyframes)"
    )
    keyframe_translation_m: float = Field(
        0.1, gt=0, description="a frame is a keyframe when its camera moved farther than this since the last "
        "keyframe, metres"
    )
    keyframe_rotation_deg: float = Field(
        10.0, gt=0, le=180, description="a frame is a keyframe when its camera turned more than this since the last "
        "keyframe, degrees"
    )
    keyframe_novel_fraction: float | None = Field(
        0.2, gt=0, le=1, description="a frame is a keyframe when more than this fraction of its valid depth pixels "
        "was not seen by the last keyframe (outside its image, no depth there, or a disocclusion); None = only "
        "motion decides, fraction"
    )
    keyframe_pixel_stride: int = Field(
        8, ge=1, description="the novel-pixel test samples every n-th depth pixel in each direction, pixels"
    )
    keyframe_depth_tolerance: float = Field(
        0.05, gt=0, description="a pixel counts as seen by the last keyframe when their depths agree within this "
        "fraction of the depth, fraction"
    )

    @field_validator("depth_stride", mode="before")
    @classmethod
    def _stride(cls, v: Any) -> Any:
        if v == "auto" or (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 8):
            return v
        raise ValueError(f"expected 'auto' or a whole number from 1 to 8, got {v!r}")

    @field_validator("floors")
    @classmethod
    def _storeys(cls, floors: list[PinnedFloor] | None) -> list[PinnedFloor] | None:
        if floors is None:
            return floors
        if not floors:
            raise ValueError("empty: list at least one floor, or leave it out (null) to find them")
        z = [f.floor_z_m for f in floors]
        for i in range(1, len(z)):
            if z[i] - z[i - 1] < MIN_STOREY_M:
                raise ValueError(f"floor {i} (floor_z_m {z[i]}) must lie at least {MIN_STOREY_M} m above floor "
                                 f"{i - 1} (floor_z_m {z[i - 1]}); list the floors lowest first")
        return floors

    @model_serializer(mode="wrap")
    def _without_unpinned_floors(self, handler) -> dict:
        """Floors not pinned are left out of the section's value: digests of scenes without them stay as they were."""
        return {k: v for k, v in handler(self).items() if not (k == "floors" and v is None)}

    @model_validator(mode="after")
    def _ranges(self) -> "ReconstructParams":
        if self.obstacle_min_height_m >= self.obstacle_max_height_m:
            raise ValueError("obstacle_min_height_m must be below obstacle_max_height_m")
        if self.floors is not None:
            if self.floor_z_m is not None:
                raise ValueError("give either floor_z_m (one floor) or floors (a building), not both")

        if self.sdf_trunc_m < self.voxel_size_m:
            raise ValueError("sdf_trunc_m must be at least voxel_size_m")
        return self


class NavchatGrid(Section):
    """The grid navchat's goal files (objects.json, final.json) give cells on (pipeline.goals.navchat)."""

    origin: Literal["first_pose", "recon_grid"] = Field(
        "first_pose", description="first_pose: navchat's own frame, anchored at the scene's first recorded pose "
        "(anchor_cell), columns to its initial right, rows to its initial backward direction; recon_grid: cells on "
        "zipon's north-up recon grid"
    )
    anchor_cell: tuple[int, int] = Field((300, 300), description="(col, row) of the first pose (navchat: 300, 300)")
    cell_size_m: float = Field(0.05, gt=0, description="cell edge, metres (navchat: 0.05)")
    rounding: Literal["trunc", "round"] = Field(
        "trunc", description="position -> cell: int() truncation toward zero (navchat's poses) or round (its voxels)"
    )


class GoalsParams(Section):
    """Objects -> personalized goals with the four kinds of feedback (``goals.zarr``)."""

    seed: int = Field(0, description="seed of goal selection and persona names (owners, manufacturers, years)")
    objects: Literal["auto", "gt", "file", "navchat"] = Field(
        "auto", description="where objects come from: the simulator's ground truth in frames.zarr ('gt'), "
        "objects_files[scene] ('file'), navchat_dirs[scene] ('navchat'); 'auto': gt, else file, else navchat"
    )
    objects_files: dict[str, str] = Field(
        default_factory=dict, description="scene -> objects YAML/JSON (pipeline.goals.objects.ObjectSet layout), "
        "relative to params.yaml"
    )
    navchat_dirs: dict[str, str] = Field(
        default_factory=dict, description="scene -> folder with navchat's objects.json (+ final.json), cells on "
        "goals.navchat_grid, relative to params.yaml"
    )
    navchat_grid: NavchatGrid = NavchatGrid()
    navchat_max_outside: float = Field(
        0.25, ge=0, le=1, description="refuse navchat objects when more than this fraction of them lie outside the "
        "observed map (less than half of their cells observed: a wrong navchat_grid); fewer are warned about"
    )
    edits: dict[str, str] = Field(
        default_factory=dict, description="scene -> imported goals document (written by 'zipon goals import', "
        "content-addressed so an edit changes the params digest), relative to params.yaml"
    )
    edits_missing_objects: Literal["error", "drop"] = Field(
        "error", description="an edited goal whose objects no longer exist: fail, or drop the goal (reported)"
    )
    max_goals: int = Field(12, gt=0, description="goals per scene at most")
    mix: tuple[float, float, float] = Field(
        (1 / 3, 1 / 3, 1 / 3), description="wanted shares of big, small and ambiguous goals (paper: 39/41/37)"
    )
    same_goal_radius_m: float = Field(
        2.0, ge=0, description="same class, room, colour and material within this many metres = one same_goal group"
    )
    landmark_radius_m: float = Field(1.0, gt=0, description="landmarks: footprint distance at most this, metres")
    max_landmarks: int = Field(3, ge=0, description="landmarks named per goal at most")
    landmark_min_area_m2: float = Field(0.1, ge=0, description="small objects below this footprint are not salient")
    exclude_classes: tuple[str, ...] = Field((), description="classes never chosen as goals")

    @field_validator("mix")
    @classmethod
    def _mix(cls, v):
        if min(v) < 0 or sum(v) <= 0:
            raise ValueError("mix: three non-negative shares with a positive sum")
        return v


class RunParams(Section):
    """Scheduling, devices, batch sizes and threads: never change an artifact, so in no digest.

    Changing them rebuilds nothing (a test checks every stage's config ignores them)."""

    scheduler: str = Field(
        "sync",
        description="'sync' (one process), 'threads', 'processes', or a dask.distributed scheduler "
        "address such as tcp://10.0.0.5:8786",
    )
    workers: int = Field(2, gt=0, description="local workers for 'threads' / 'processes'")
    threads_per_worker: int = Field(1, gt=0, description="native threads (BLAS/torch/open3d) inside a worker")
    device: str = Field(
        "auto", description="torch device of the encoders: cpu, cuda, cuda:N (the N-th GPU) or auto (cuda when "
        "available, else cpu)"
    )
    fusion_device: str = Field("cpu", description="torch device of the map fusion (cpu, cuda, cuda:N or auto)")
    precision: Literal["fp32", "bf16", "fp16"] = Field(
        "fp32", description="the encoders' forward passes under torch autocast in this precision (bf16 / fp16 on a "
        "GPU; fp32 = off, the default); features are handed on as float32 unit vectors either way"
    )
    encoder_resources: dict[str, float] = Field(
        default_factory=dict, description="dask worker resources each map chunk task (encoder + fusion) asks for, "
        "e.g. {GPU: 1}: those tasks then run only on workers started with them (dask worker --resources GPU=1) and "
        "every other task anywhere; 'processes' gives its local workers these resources; {} = any worker"
    )
    encoder_batch_size: int = Field(4, gt=0, description="images per encoder forward pass")
    torch_threads: int = Field(0, ge=0, description="torch CPU threads of the encoders (0 = leave torch's default)")
    recon_tile_m: float = Field(
        16.0, ge=0, description="reconstruct fuses the TSDF volume in square tiles of this side (whole 0.4 m blocks at "
        "the default voxel), one at a time, so its memory depends on the tile, not on the floor's area; the outputs "
        "are the same bytes for any tile size (pipeline.recon.tiles); 0 = one volume for the whole scene, metres"
    )
    map_fold_cache: bool = Field(
        True, description="keep each map's fold of its complete frame chunks beside it (data/artifacts/<scene>/"
        ".<stage>.fold, as big as the map's fp32 sums) so a rerun after frames were appended fuses only the new ones"
    )

    @field_validator("device", "fusion_device")
    @classmethod
    def _device(cls, v: str) -> str:
        if re.fullmatch(r"cpu|auto|cuda(:[0-9]+)?", v):
            return v
        raise ValueError(f"{v!r} is not a device: use cpu, cuda, cuda:N (N = 0, 1, ...) or auto")

    @field_validator("encoder_resources")
    @classmethod
    def _resources(cls, v: dict[str, float]) -> dict[str, float]:
        bad = {k: n for k, n in v.items() if not n > 0}
        if bad:
            raise ValueError(f"resource amounts must be positive, got {bad}")
        return v

    @field_validator("scheduler")
    @classmethod
    def _scheduler(cls, v: str) -> str:
        if v in ("sync", "threads", "processes") or "://" in v:
            return v
        raise ValueError(f"{v!r} is not a scheduler: use sync, threads, processes or a dask.distributed "
                         "address such as tcp://10.0.0.5:8786")


class Params(Section):
    """The whole ``params.yaml``."""

    scenes: dict[str, SceneSource] = Field(description="scene name -> raw source; 'zipon run' builds all of them")
    run: RunParams = RunParams()
    grid: GridParams = GridParams()
    simulate: SimulateParams = SimulateParams()
    ingest: IngestParams = IngestParams()
    reconstruct: ReconstructParams = ReconstructParams()
    encoders: EncodersParams = EncodersParams()
    maps: MapsParams = MapsParams()
    query: QueryParams = QueryParams()
    task: TaskParams = TaskParams()
    goals: GoalsParams = GoalsParams()
    routes: RoutesParams = RoutesParams()
    eval: EvalParams = EvalParams()

    @field_validator("scenes")
    @classmethod
    def _scene_names(cls, scenes: dict[str, SceneSource]) -> dict[str, SceneSource]:
        for name in scenes:
            if not name or any(ch in name for ch in "/\\ .") or name.startswith("-"):
                raise ValueError(f"scene name {name!r} must be a plain identifier (letters, digits, _ -)")
        return scenes
