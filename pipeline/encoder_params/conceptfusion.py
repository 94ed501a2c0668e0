"""Settings of the ``conceptfusion`` encoder (:mod:`pipeline.encoders.conceptfusion`) and its region generator
(:mod:`pipeline.encoders.regions`), section ``encoders.conceptfusion``: its ``params_model``, in the torch-free
module named after the encoder's (the params schema imports it)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from pipeline.section import CellSize, Section


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
