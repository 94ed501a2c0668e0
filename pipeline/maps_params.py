"""The map sections of ``params.yaml``: ``maps`` (fusion of the vlmap / cfmap stages) and ``query`` (text queries on
built maps, in no digest): a leaf of the params schema (:mod:`pipeline.config` imports it; it imports no map code)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from pipeline.section import DepthRange, Section


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
    hold_features_mb: float = Field(
        512, ge=0, description="from a map's second query on, its features are held in memory as float32 (twice "
        "this) when their stored float16 size is at most this, so a repeated query costs one product; a larger map "
        "is read tile by tile for every query (memory: one tile's features); with levels max a cfmap's voxel "
        "features are held likewise (float16 as stored, if they fit this) or read block by block; 0 = always read "
        "tile by tile, MB"
    )
    levels: Literal["top", "max"] = Field(
        "top", description="top: a cell is scored by its top-down feature (its highest level: a table hides the "
        "chair under it); max: a cfmap that stores voxels (maps.cfmap_voxels) scores each cell by its best height "
        "level for the query (pipeline.maps.levels: finds the chair under the table, a picture on a wall); a vlmap "
        "has one level per cell, so max scores it as top"
    )
