"""Typed configuration: ``params.yaml`` validated at load, one section per stage.

Every tunable lives here, documented once (the schema). A stage reads only its own section(s), and the digest of
exactly those keys decides whether it is stale (:mod:`pipeline.stageconfig`). Reading a params file, ``-S``
overrides, moved keys and writing ``params.yaml`` live in :mod:`pipeline.paramsfile`. Errors name the key:
``params.yaml: ingest.block_frames: Input should be greater than 0``.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_serializer, model_validator

from pipeline.perception_params import DetectorParams, SimulatedCFParams, SimulatedLSegParams
from pipeline.section import Section


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

class DepthRange(Section):
    """Base of the sections that read depth images (simulate, ingest, reconstruct, maps): the valid depth band
    ``[depth_min_m, depth_max_m]``, metres, checked once here. Each section keeps its own keys (and may change
    their defaults and descriptions); what falls outside the band is that stage's business (stored as 0,
    ignored, not fused)."""

    depth_min_m: float = Field(0.1, ge=0, description="nearest valid depth, metres")
    depth_max_m: float = Field(10.0, gt=0, description="farthest valid depth, metres")

    @model_validator(mode="after")
    def _depth_range(self) -> "DepthRange":
        if self.depth_min_m >= self.depth_max_m:
            raise ValueError(f"depth_min_m ({self.depth_min_m:g}) must be below depth_max_m ({self.depth_max_m:g})")
        return self


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


class IngestTopics(Section):
    """ROS 2 topic names; ``None`` means auto-detect from the message types in the log."""

    rgb: str | None = None
    depth: str | None = None
    camera_info: str | None = None
    instance: str | None = Field(None, description="a 16UC1 instance-id image topic (auto: a name with 'instance')")
    pose: str | None = Field(None, description="a geometry_msgs/PoseStamped topic of the camera pose")
    tf_world_frame: str | None = Field(None, description="/tf parent frame to chain from (auto: the root)")
    tf_camera_frame: str | None = Field(None, description="/tf child frame of the optical camera (auto)")
    depth_camera_info: str | None = Field(
        None, description="CameraInfo of the depth camera (auto: the one in the depth topic's namespace); depth "
        "on another frame or with other intrinsics than colour is registered into the colour camera"
    )


class CameraOverride(Section):
    """Pinhole intrinsics in pixels (no distortion) for datasets that do not store them."""

    fx: float = Field(gt=0, description="focal length along x, pixels")
    fy: float = Field(gt=0, description="focal length along y, pixels")
    cx: float = Field(description="principal point x, pixels")
    cy: float = Field(description="principal point y, pixels")


class IngestParams(DepthRange):
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
    compression_level: int = Field(
        1, ge=1, le=9, description="level of the blosc compressor of frames.zarr (zstd 1: ~3.7 ms per 640x480 "
        "colour frame at 3.6x; level 3: ~9 ms at 4.3x, which halves ingest throughput)"
    )
    codec: Literal["zstd", "lz4"] = Field(
        "zstd", description="blosc codec of frames.zarr: zstd (smaller) or lz4 (about 10x faster to write camera "
        "colour; see benchmarks/bench_ingest.py)"
    )
    topics: IngestTopics = IngestTopics()
    navchat_camera_height_m: float = Field(0.88, gt=0, description="camera height above navchat's base pose")
    folder_fps: float = Field(
        30.0, gt=0, description="frame rate assumed for datasets without timestamps (7-Scenes, navchat)"
    )
    max_stream_lag_s: float = Field(
        2.0, gt=0, description="a colour frame is decided once any stream is this far ahead of it (bounds memory "
        "when a stream stalls or stops), seconds"
    )
    tum_camera: Literal["auto", "fr1", "fr2", "fr3"] = Field(
        "auto", description="TUM RGB-D intrinsics set; 'auto' reads freiburg1/2/3 (fr1/2/3) from the folder name, "
        "else fr1"
    )
    camera_override: CameraOverride | None = Field(
        None, description="pinhole intrinsics replacing a folder format's defaults (TUM, 7-Scenes, navchat)"
    )
    world_up: Literal["dataset", "auto", "+z", "-z", "+y", "-y", "+x", "-x"] = Field(
        "dataset", description="the source world's up axis, rotated to zipon's +z: 'dataset' = the reader's "
        "documented convention (7-Scenes -y, levelled on the floor when one is seen; everything else +z), 'auto' = "
        "the normal of the dominant floor plane "
        "seen in the first world_up_auto_frames frames (logged and stored in frames.zarr attrs world_up)"
    )
    world_up_auto_frames: int = Field(
        48, gt=0, description="frames at the start of the log that world_up 'auto' (and 7-Scenes' levelling) looks "
        "for the floor in"
    )
    pose_orthonormal_tol: float = Field(
        1e-3, gt=0, description="poses stored as matrices (7-Scenes, Replica, ScanNet) whose rotation is orthonormal "
        "within this are re-orthonormalised (SVD); beyond it they are refused (real 7-Scenes: ~2.5e-4)"
    )


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
            if not self.floors:
                raise ValueError("floors is empty: list at least one floor, or leave it out (null) to find them")
            z = [f.floor_z_m for f in self.floors]
            for i in range(1, len(z)):
                if z[i] - z[i - 1] < MIN_STOREY_M:
                    raise ValueError(f"floors[{i}].floor_z_m {z[i]} must lie at least {MIN_STOREY_M} m above "
                                     f"floors[{i - 1}].floor_z_m {z[i - 1]} (lowest floor first)")
        if self.sdf_trunc_m < self.voxel_size_m:
            raise ValueError("sdf_trunc_m must be at least voxel_size_m")
        return self


CellSize = tuple[Annotated[int, Field(gt=0)], Annotated[int, Field(gt=0)]]  # (height, width)


class LSegParams(Section):
    """LSeg (DPT head on ViT-L/16, CLIP ViT-B/32 text space), loaded from the public LSeg checkpoint."""

    weights: str | None = Field(
        None,
        description="path to the LSeg checkpoint (e.g. demo_e200.ckpt: a pytorch-lightning ckpt whose state_dict "
        "keys start with 'net.', or a bare state dict); None = no weights, an error when lseg is chosen",
    )
    crop_size: int = Field(480, gt=0, multiple_of=32, description="sliding-window crop edge, pixels (VLMaps: 480)")
    base_size: int = Field(520, gt=0, description="the long image side is resized to this before cropping (VLMaps: 520)")
    stride_rate: float = Field(2.0 / 3.0, gt=0, le=1, description="window stride as a fraction of crop_size")
    out_size: CellSize = Field((120, 160), description="feature map (height, width) returned, cells")


class MaskClipParams(Section):
    """MaskCLIP dense features from an open_clip ViT (value embeddings of the last block, no query-key attention)."""

    arch: str = Field(
        "ViT-B-32",
        description="open_clip model name (a ViT); OpenAI-trained weights need the '-quickgelu' variant "
        "(e.g. ViT-B-32-quickgelu): the state dict is the same, the activation is not",
    )
    weights: str | None = Field(
        None, description="local open_clip weights file (.pt/.bin/.safetensors); None = error when maskclip is chosen"
    )
    input_size: CellSize = Field(
        (480, 640), description="(height, width) the image is resized to before the ViT; multiples of the patch size"
    )
    out_size: CellSize | None = Field(None, description="feature (height, width); None = the patch grid")


class RegionParams(Section):
    """How ConceptFusion cuts a frame into regions."""

    generator: Literal["rgbd", "gt", "sam"] = Field(
        "rgbd",
        description="'rgbd': felzenszwalb graph segmentation of colour + depth; 'gt': ground-truth instance masks "
        "(simulated data); 'sam': segment-anything automatic masks (needs the package and sam_checkpoint)",
    )
    work_height: int = Field(120, gt=8, description="rgbd: frames are segmented at this height, pixels")
    felzenszwalb_scale: float = Field(200.0, gt=0, description="rgbd: felzenszwalb scale (larger = bigger regions)")
    felzenszwalb_sigma: float = Field(
        0.0, ge=0, description="rgbd: gaussian pre-smoothing, pixels (0: the area-downscaled frame is smooth "
        "enough, and smoothing a depth step leaves one-pixel strip regions along it)"
    )
    depth_weight: float = Field(
        0.5, ge=0, description="rgbd: weight of depth (per metre) against CIELAB colour (per 100 units) in the cut"
    )
    min_area_frac: float = Field(0.002, ge=0, lt=1, description="regions smaller than this image fraction are dropped")
    max_regions: int = Field(64, gt=0, description="keep at most this many regions per frame (largest first)")
    gt_background: bool = Field(True, description="gt: instance id 0 (walls, floor) forms one region")
    sam_checkpoint: str | None = Field(None, description="sam: path to a local SAM checkpoint")
    sam_model_type: str = Field("vit_h", description="sam: segment_anything model type of the checkpoint")


class ConceptFusionParams(Section):
    """ConceptFusion pixel features: global + per-region CLIP features fused by softmax-of-cosine weights."""

    arch: str = Field(
        "ViT-B-32", description="open_clip model name (OpenAI-trained weights: ViT-B-32-quickgelu, see maskclip.arch)"
    )
    weights: str | None = Field(None, description="local open_clip weights file; None = error when chosen")
    softmax_temperature: float = Field(1.0, gt=0, description="softmax over regions of cos(global, local) / T")
    out_size: CellSize = Field((120, 160), description="feature (height, width); ConceptFusion stores 120x160")
    regions: RegionParams = RegionParams()


class TorchScriptParams(Section):
    """Any user-exported dense encoder: two TorchScript files, or a python factory 'pkg.mod:factory'."""

    image_file: str | None = Field(
        None, description="TorchScript module: float (B,3,H,W) RGB in [0,1] -> (B,D,h,w) features"
    )
    text_file: str | None = Field(None, description="TorchScript module: list[str] -> (T,D) features")
    factory: str | None = Field(
        None,
        description="'pkg.mod:factory' returning an object with encode_image(x (B,3,H,W) [0,1]) -> (B,D,h,w) and "
        "encode_text(list[str]) -> (T,D); used instead of the two files",
    )
    input_size: CellSize | None = Field(None, description="resize images to (height, width) first; None = as is")
    name: str = Field("torchscript", description="encoder name recorded in the maps' attrs")
    version: str = Field("1", description="encoder version recorded in the maps' attrs")

    @model_validator(mode="after")
    def _one_source(self) -> "TorchScriptParams":
        if self.factory is not None and (self.image_file or self.text_file):
            raise ValueError("give either factory or image_file + text_file, not both")
        return self


class OracleParams(Section):
    """DIAGNOSTIC encoder for simulated scenes: features from ground-truth instance classes, never a model."""

    dim: int = Field(512, gt=1, description="feature dimension")
    seed: int = Field(0, description="seed of the per-word random unit vectors and of the confusion/noise draws")
    color_weight: float = Field(0.5, ge=0, description="weight of colour words against the class word (1)")
    material_weight: float = Field(0.3, ge=0, description="weight of material words against the class word (1)")
    confusion: float = Field(0.0, ge=0, le=1, description="probability an instance takes another class's word")
    noise_std: float = Field(
        0.0, ge=0, description="per-component std of gaussian noise added to each cell before renormalising "
        "(noise norm ~ noise_std * sqrt(dim))"
    )
    out_size: CellSize = Field((120, 160), description="feature (height, width), cells")


class EncodersParams(Section):
    """Open-vocabulary pixel/text encoders used by the map stages and the evaluator.

    No weights are ever downloaded: a real encoder without a ``weights`` file is a ConfigError.
    The oracle is a diagnostic built from ground truth; it runs only where chosen explicitly.
    """

    vlmap: str = Field("lseg", description="encoder of the vlmap stage (VLMaps uses lseg); a built-in name or "
                       "one an installed package registers in the zipon.encoders entry points")
    cfmap: str = Field("conceptfusion", description="encoder of the cfmap stage (built-in or plugin, as vlmap)")
    simulated: str | None = Field(
        "perception",
        description="encoder used INSTEAD of vlmap/cfmap for simulated scenes: 'perception' = simulated perception "
        "models (simulated_lseg for the vlmap, simulated_cf for the cfmap), 'oracle' = the ground-truth DIAGNOSTIC "
        "(perfect features, an upper bound, labelled so in every result); None = simulated scenes use vlmap/cfmap "
        "like real ones",
    )
    lseg: LSegParams = LSegParams()
    maskclip: MaskClipParams = MaskClipParams()
    conceptfusion: ConceptFusionParams = ConceptFusionParams()
    torchscript: TorchScriptParams = TorchScriptParams()
    oracle: OracleParams = OracleParams()
    simulated_lseg: SimulatedLSegParams = SimulatedLSegParams()
    simulated_cf: SimulatedCFParams = SimulatedCFParams()
    plugins: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="plugin encoder name -> its settings, checked against the params class the "
        "plugin declares (its params_model); part of a map's digest when the map uses that plugin"
    )

    @field_validator("plugins")
    @classmethod
    def _plugin_settings(cls, plugins: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        """Each plugin's settings validated by the class its encoder declares (importing the plugin's module; whether
        it is an Encoder is checked when it is built)."""
        from pydantic import ValidationError

        from pipeline import plugins as registry

        for name, settings in plugins.items():
            encoder = registry.load_class(registry.ENCODERS_GROUP, name, object, "a class", "encoder")
            if encoder is None:
                raise ValueError(f"{name}: settings for an encoder no installed package registers (zipon.encoders "
                                 "entry points)")
            if getattr(encoder, "params_model", None) is None:
                raise ValueError(f"{name}: the encoder takes no settings (it declares no params_model)")
            try:
                encoder.params_model.model_validate(settings)
            except ValidationError as err:
                e = err.errors()[0]
                where = ".".join(map(str, (name, *e["loc"])))
                raise ValueError(f"{where}: {e['msg'].removeprefix('Value error, ')}") from None
        return plugins

    @field_validator("vlmap", "cfmap", "simulated")
    @classmethod
    def _known_encoder(cls, name: str | None) -> str | None:
        from pipeline import plugins

        # 'perception': simulated_lseg for the vlmap, simulated_cf for the cfmap
        built_in = [*plugins.BUILT_IN_ENCODERS, "perception"]
        if name is None or name in built_in:  # known without reading the installed packages
            return name
        installed = plugins.names(plugins.ENCODERS_GROUP)
        if name not in installed:
            raise ValueError(f"unknown encoder {name!r}: built-in {built_in}, installed plugins "
                             f"(zipon.encoders entry points) {installed}")
        return name


class MapsParams(DepthRange):
    """Semantic map fusion (stages ``vlmap`` / ``cfmap``); query settings are in ``query``.

    Height rule (both maps): space above the grid is cut into levels of ``level_height_m``
    between ``floor + min_height_m`` and ``floor + max_height_m``; a cell's top-down feature is the
    weighted mean of the points in its HIGHEST observed level (navchat's "top voxel per column",
    which also matches the top-down colour map and GT footprints, where taller parts win).
    """

    block_frames: int = Field(16, gt=0, description="frames read, encoded and fused per block")
    chunk_frames: int = Field(
        256, gt=0, description="frames of one chunk: chunks (fixed by frame index) are fused as separate tasks on every "
        "worker and folded in order, so the map does not depend on the workers; a rerun after frames were appended "
        "reuses the fold of the unchanged complete chunks (best a multiple of block_frames)"
    )
    depth_min_m: float = Field(0.1, ge=0, description="depth below this is not fused, metres")
    depth_max_m: float = Field(5.0, gt=0, description="depth beyond this is not fused (noise grows), metres")
    max_depth_jump: float = Field(
        0.1, ge=0, description="a pixel whose depth differs from a 4-neighbour by more than this fraction of its "
        "depth lies on a depth edge (flying pixel) and is not fused; 0 = keep all"
    )
    min_height_m: float = Field(-0.05, description="lowest fused point, metres above the floor (reconstruction's floor_z)")
    max_height_m: float = Field(2.0, gt=0, description="highest fused point (ceilings left out), metres above the floor")
    level_height_m: float = Field(0.1, gt=0, description="height of one level (voxel) of the height rule, metres")
    vlmap_weight_sigma_m: float | None = Field(
        None, gt=0, description="vlmap point weight exp(-d^2 / 2 sigma^2) of camera distance d; None = every point "
        "weighs 1 (VLMaps' count-weighted mean)"
    )
    cfmap_weight_sigma_m: float | None = Field(
        0.6, gt=0, description="cfmap point weight exp(-d^2 / 2 sigma^2) (ConceptFusion's confidence, sigma 0.6); "
        "None = count weights"
    )
    cfmap_voxels: bool = Field(True, description="cfmap also stores its sparse 3D voxel feature map")
    fill_radius_m: float = Field(
        0.3, ge=0, description="unobserved cells recon does not mark free (the unseen tops of tall objects) take the "
        "feature of the nearest observed cell within this distance; filled cells have count 0; 0 = no filling"
    )
    tile_cells: int = Field(64, gt=0, description="spatial tile edge (cells) of the stored map's chunks")
    keyframes_only: bool = Field(
        False, description="fuse only the frames reconstruct fused (its keyframes, with reconstruct.keyframes; "
        "recon.zarr 'fused'); false = every frame with a pose, keyframe or not"
    )
    @model_validator(mode="after")
    def _ranges(self) -> "MapsParams":
        if self.min_height_m >= self.max_height_m:
            raise ValueError("min_height_m must be below max_height_m")
        if (self.max_height_m - self.min_height_m) / self.level_height_m > 1000:
            raise ValueError("level_height_m is too small for the height band (more than 1000 levels)")
        return self


class QueryParams(Section):
    """Text queries on built maps (``zipon query``, the evaluator's map agents). Never part of a digest:
    changing a query setting rebuilds nothing."""

    background: tuple[str, ...] = Field(
        ("other", "floor", "wall", "ceiling"),
        description="background prompts a query competes with per cell (VLMaps: categories + 'other'); "
        "a cell is a candidate where the query's score beats every background prompt",
    )
    temperature: float | None = Field(
        None, gt=0, description="softmax temperature of the heatmap; None = the encoder's own, else 0.1"
    )
    min_probability: float = Field(
        0.5, ge=0, le=1, description="a cell wins when the query beats every background prompt AND its heatmap "
        "probability is at least this (0.5: the query outweighs all background prompts together); 0 = argmax only"
    )
    min_candidate_area_m2: float = Field(0.01, ge=0, description="smaller winning components are not candidates")
    min_candidate_score: float = Field(
        0.7, ge=0, le=1, description="components whose mean heatmap probability is below this are not candidates "
        "(drops cells the query wins only because every prompt scores about as low; 0.7 lifts the demo scenes' "
        "top-candidate hit rate from 0.947/0.971 to 0.967/0.995 with the oracle, benchmarks/quality_maps.py)"
    )
    max_candidates: int = Field(20, gt=0, description="at most this many candidates per query")
    query_rank: int = Field(
        64, ge=0, description="maps with at least query_lowrank_min_cells cells are scored through a rank-k basis "
        "of their features, with exact rescoring of every cell that could win (exact wins and candidates); 0 = exact"
    )
    query_lowrank_min_cells: int = Field(50_000, gt=0, description="smaller maps are always scored exactly")
    levels: Literal["top", "max"] = Field(
        "top", description="top: a cell is scored by its top-down feature (its highest level: a table hides the "
        "chair under it); max: a cfmap that stores voxels (maps.cfmap_voxels) scores each cell by its best height "
        "level for the query (pipeline.maps.levels: finds the chair under the table, a picture on a wall); a vlmap "
        "has one level per cell, so max scores it as top"
    )


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


class TaskParams(Section):
    """The ZIPON task's facts, one home: the action space, the success rule, and how a walk to a goal is planned.

    Read by the goals stage (goal regions, procedural feedback), the routes stage (episodes, replay) and the
    evaluator (``orion_eval``), which takes the action space and success radius from ``routes.zarr`` and refuses
    params that disagree with it. Not here: ``simulate.hfov_deg`` is the field of view of the camera that
    RECORDS a simulated scene (a real log brings its own intrinsics); ``hfov_deg`` here is the agent's ego view,
    a fact of the task that holds for real and simulated scenes alike. ``eval.goto_stop_radius_m`` is how close
    the evaluator's agents approach an object they found, a choice of the agents, not of the task.
    """

    step_m: float = Field(0.25, gt=0, description="forward action, metres (paper: 0.25)")
    turn_deg: float = Field(15.0, gt=0, le=180, description="turn action (left / right), degrees (paper: 15)")
    success_m: float = Field(
        1.5, gt=0, description="success radius: an episode succeeds within this distance of the goal's footprint "
        "(paper: 1.5); a goal's region is the navigable cells this close that see its mass centre, metres"
    )
    hfov_deg: float = Field(
        90.0, gt=0, lt=180, description="horizontal field of view of the agent's ego view: success needs the goal's "
        "mass centre inside it (paper: 90); the reference routes are replayed with it, degrees"
    )
    stop_radius_m: float = Field(
        1.0, gt=0, description="a walk to a goal (the reference routes, the procedural feedback of goals.zarr and of "
        "the simulated user) aims for goal-region cells within this distance of the footprint "
        "(pipeline.nav.region.route_target), metres"
    )
    clearance_m: float = Field(
        0.1, ge=0, description="planned paths keep this far from non-navigable cells, beyond recon's robot radius: "
        "the same for the reference routes and the agents, so SPL compares paths planned alike, metres"
    )

    @model_validator(mode="after")
    def _radii(self) -> "TaskParams":
        if self.stop_radius_m + self.step_m / 2 > self.success_m:
            raise ValueError("stop_radius_m + step_m / 2 must not exceed success_m (routes must end in success)")
        return self


class RoutesParams(Section):
    """Goals + navigable grid -> episodes, geodesic routes and procedural text (``routes.zarr``).

    The action space, success rule and planning margins are the task's (``task``)."""

    seed: int = Field(0, description="seed of the start poses")
    episodes_per_goal: int = Field(3, gt=0, description="episodes (start poses) per goal")
    min_geodesic_m: float = Field(2.0, ge=0, description="start poses are at least this geodesic distance away")
    cross_floor_per_goal: int = Field(
        1, ge=0, le=20, description="a building's episodes per goal from each other floor the stairs join to it (0: "
        "none); a single-floor scene has none")

    @model_serializer(mode="wrap")
    def _unset_building_keys(self, handler) -> dict:
        # a building's key at its default is not written, so a single-floor scene's routes digest is as before it
        data = handler(self)
        if data.get("cross_floor_per_goal") == 1:
            data.pop("cross_floor_per_goal")
        return data


class LLMParams(Section):
    """Optional LLM-backed user / agent through an OpenAI-compatible HTTP endpoint (off unless base_url is set)."""

    base_url: str | None = Field(
        None, description="e.g. http://127.0.0.1:8000/v1 (POST {base_url}/chat/completions); None = off, nothing "
        "is contacted"
    )
    model: str = Field("gpt-4o-mini", description="model name sent in each request")
    api_key_env: str | None = Field("OPENAI_API_KEY", description="environment variable holding the bearer key "
                                    "(unset variable = no Authorization header)")
    roles: Literal["user", "agent", "both"] = Field("both", description="which side the LLM plays")
    timeout_s: float = Field(30.0, gt=0, description="per-request timeout, seconds")
    max_requests: int = Field(200, gt=0, description="requests per evaluation run at most (then a StageError)")
    temperature: float = Field(0.0, ge=0, description="sampling temperature sent with each request")


class EvalParams(Section):
    """The light online evaluator (``zipon eval``, package ``orion_eval``): agents, simulated user, metrics.

    Actions: TurnLeft / TurnRight ``task.turn_deg`` (15 deg), MoveForward ``task.step_m`` (0.25 m), Talk, as
    ``routes.zarr`` records them. An episode ends on success or after ``max_talk_turns`` Talk turns (or
    ``max_steps`` actions). Method and feedback names are checked against their registries when the evaluator
    runs (:data:`orion_eval.agents.AGENTS`, :data:`orion_eval.user.FEEDBACK_SETTINGS`, which are derived from
    :data:`pipeline.goals.feedback.FEEDBACK_KINDS`), so a name is spelled once, in its registry.
    """

    scenes: tuple[str, ...] | None = Field(None, description="scenes to evaluate; None = every scene in 'scenes'")
    methods: tuple[str, ...] | None = Field(
        None, description="agents by name: the built-in ones (orion_eval.agents.AGENTS), plugins (zipon.agents "
        "entry points), llm (with eval.llm); None = every built-in agent, in the registry's order"
    )
    feedback: tuple[str, ...] | None = Field(
        None, description="simulated user's settings (orion_eval.user.FEEDBACK_SETTINGS: no interaction, yes/no, "
        "one per feedback kind of the goals, mixed); None = all of them"
    )
    seeds: tuple[int, ...] = Field((0, 1, 2, 3, 4), description="seeds (start pose choice, user draws); "
                                   "results are means over seeds")
    max_talk_turns: int = Field(5, gt=0, description="I_max: Talk turns per episode at most (paper: 5)")
    max_steps: int = Field(600, gt=0, description="movement actions per episode at most")
    success_rule: Literal["paper", "navchat"] = Field(
        "paper", description="'paper': within task.success_m of the goal, its mass centre in the ego view's "
        "field of view (task.hfov_deg) and in line of sight; 'navchat': navchat's tighter distance/angle bands"
    )
    camera_height_m: float | None = Field(
        None, gt=0, description="ego camera height above the floor; None = median height of the recording's poses"
    )
    orion_map: Literal["vlmap", "cfmap"] = Field("vlmap", description="the semantic map ORION retrieves from")
    detect_encoder: str | None = Field(
        None, description="encoder of detect_object ('vlmap' / 'cfmap' / an encoder name); None = the encoder the "
        "VLMap was built with"
    )
    detect_size: tuple[int, int] = Field((24, 32), description="ego view (height, width) ray-cast for detection")
    detect_max_range_m: float = Field(3.5, gt=0, description="detections farther than this are ignored, metres")
    detect_min_pixels: int = Field(4, gt=0, description="a detection needs this many winning ego-view pixels")
    explore_radius_m: float = Field(2.5, gt=0, description="a spin marks cells this close (in sight) as explored")
    explore_max_targets: int = Field(12, gt=0, description="frontier targets visited per search at most")
    reject_radius_m: float = Field(0.75, ge=0, description="candidates this close to a rejected place are skipped")
    goto_stop_radius_m: float = Field(
        1.25, gt=0, description="the agents' goto_object stops at the nearest place this close to a found object's "
        "cells from which its centre is in sight (an agent's choice; walks to a ground-truth goal use "
        "task.stop_radius_m), metres")
    workers: int = Field(2, gt=0, description="processes evaluating scenes in parallel (1 = serial)")
    detector: DetectorParams = Field(
        DetectorParams(), description="simulated open-vocabulary detector of the cow and orion agents (simulated scenes)"
    )
    llm: LLMParams = LLMParams()

    @field_validator("methods", "feedback", "seeds")
    @classmethod
    def _nonempty(cls, v):
        if v is None:
            return v
        if not v:
            raise ValueError("at least one value is needed")
        if len(set(v)) != len(v):
            raise ValueError("values must be distinct")
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
