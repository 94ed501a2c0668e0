"""The ``ingest`` section of ``params.yaml`` (raw logs / dataset folders -> ``frames.zarr``): a leaf of the
params schema (:mod:`pipeline.config` imports it; it imports no reader)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from pipeline.section import DepthRange, Section


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
