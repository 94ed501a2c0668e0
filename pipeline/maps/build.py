"""Build one semantic map from ``frames.zarr`` + ``recon.zarr``: the unit of work of the vlmap/cfmap stages.

Frames stream in blocks of ``maps.block_frames``; each block is encoded in batches of
``run.encoder_batch_size`` and fused with one vectorized scatter (:mod:`pipeline.maps.fusion`), so
memory is bounded by the map (observed cells / voxels), never by the number of frames. Poses
come from ``recon.zarr`` (the poses the geometry was fused with); frames recon did not fuse are
skipped and counted.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Callable, ClassVar, Iterable

import numpy as np

from pipeline.config import EncodersParams, MapsParams, Params, RunParams, StageConfig, section_keys
from pipeline.errors import StageError
from pipeline.frames import FrameStore


class MapKind(str, Enum):
    """The two kinds of semantic map, one stage each; the value is the stage's (and params section's) name."""

    VLMAP = "vlmap"  # pixel features fused straight into the top-down cells (VLMaps)
    CFMAP = "cfmap"  # fused into sparse 3-D voxels, then projected top-down (ConceptFusion)

    def __str__(self) -> str:
        return self.value

    @property
    def fuses_voxels(self) -> bool:
        """Whether the map is fused in 3-D voxels (then projected by the height rule) rather than in cells."""
        return self is MapKind.CFMAP

    @property
    def own_fields(self) -> tuple[str, ...]:
        """The ``maps.*`` fields only this kind of map reads."""
        return KIND_FIELDS[self]

    def weight_sigma_m(self, p: MapsParams) -> float:
        """This kind's confidence-weight sigma (``maps.<kind>_weight_sigma_m``)."""
        return p.cfmap_weight_sigma_m if self is MapKind.CFMAP else p.vlmap_weight_sigma_m


# maps.* fields that only one kind of map reads
KIND_FIELDS: dict[MapKind, tuple[str, ...]] = {MapKind.VLMAP: ("vlmap_weight_sigma_m",),
                                               MapKind.CFMAP: ("cfmap_weight_sigma_m", "cfmap_voxels")}


class MapConfig(StageConfig):
    """Config of a map stage (``vlmap`` / ``cfmap``: set ``kind``): the ``maps`` fusion settings this kind reads,
    and the encoder it uses with that encoder's own settings only (``encoders.lseg.crop_size`` is not part of a
    ConceptFusion map). Query settings (``query``) and devices, batch sizes, threads (``run``) are in no digest."""

    kind: ClassVar[MapKind]
    maps: MapsParams
    encoder: str
    encoders: EncodersParams

    @classmethod
    def _other_fields(cls) -> tuple[str, ...]:
        return tuple(f for k in MapKind if k is not cls.kind for f in k.own_fields)

    @classmethod
    def _encoder(cls, params: Params, scene: str) -> tuple[str, list[str]]:
        """(encoder name, the params keys that choose it and configure it)."""
        from pipeline.encoders.choice import encoder_choice

        enc = params.encoders
        simulated = params.scenes[scene].simulated
        name = encoder_choice(enc, cls.kind.value, simulated=simulated)
        keys = ["encoders.simulated"] if simulated else []
        if not (simulated and enc.simulated is not None):
            keys.append(f"encoders.{cls.kind.value}")
        if name in EncodersParams.model_fields:
            keys.append(f"encoders.{name}")
        elif name in enc.plugins:
            keys.append(f"encoders.plugins.{name}")
        return name, keys

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        return section_keys("maps", MapsParams, exclude=cls._other_fields()) + cls._encoder(params, scene)[1]

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "MapConfig":
        name, _ = cls._encoder(params, scene)
        defaults = MapsParams()
        maps = params.maps.model_copy(update={f: getattr(defaults, f) for f in cls._other_fields()})
        enc = params.encoders
        own = ({name: getattr(enc, name)} if name in EncodersParams.model_fields
               else {"plugins": {name: enc.plugins[name]}} if name in enc.plugins else {})
        return cls(maps=maps, encoder=name, encoders=EncodersParams(**own))

    @classmethod
    def extra_inputs(cls, params: Params, scene: str) -> dict[str, str]:
        """A plugin encoder's source (package folder or module file): its code is outside zipon's import
        closure, so its content is hashed as an input of the map."""
        from pipeline.encoders.choice import plugin_source

        source = plugin_source(cls._encoder(params, scene)[0])
        return {"encoder_plugin": source} if source else {}


class VlmapConfig(MapConfig):
    kind = MapKind.VLMAP


class CfmapConfig(MapConfig):
    kind = MapKind.CFMAP


MAP_CONFIGS: dict[str, type[MapConfig]] = {cfg.kind.value: cfg for cfg in (VlmapConfig, CfmapConfig)}


def build_map(
    config: MapConfig,
    frames_path: Path,
    recon_path: Path,
    out_path: Path,
    attrs: dict,
    *,
    runtime: RunParams | None = None,
    progress: Callable[[Iterable, int, str], Iterable] | None = None,
) -> dict:
    """Fuse every frame into a new map store at ``out_path``; returns the summary figures."""
    import torch

    from pipeline.encoders import build_encoder
    from pipeline.encoders.base import resolve_device
    from pipeline.maps.fusion import TopDownAccumulator, VoxelAccumulator, fill_unseen, locate_block, point_weights
    from pipeline.maps.store import Lattice, write_map
    from pipeline.recon import Recon

    kind, p, runtime = config.kind, config.maps, runtime or RunParams()
    fs = FrameStore(frames_path)
    recon = Recon(recon_path)
    if fs.n_frames != len(recon.fused):
        raise StageError(f"{recon_path}: holds {len(recon.fused)} poses but {frames_path} has {fs.n_frames} frames "
                         f"(recon from another frame store? rerun: zipon run --force --stage reconstruct)")
    poses = recon.poses
    usable = recon.fused & np.isfinite(poses).all(axis=(1, 2))
    encoder = build_encoder(config.encoders, config.encoder, runtime=runtime)
    encoder.bind_scene(fs.ground_truth)
    lattice = Lattice(recon.grid, recon.floor_z, p.min_height_m, p.max_height_m, p.level_height_m)
    device = resolve_device(runtime.fusion_device)
    sigma = kind.weight_sigma_m(p)
    acc = (VoxelAccumulator if kind.fuses_voxels else TopDownAccumulator)(lattice, encoder.dim, device=device)
    blocks = fs.iter_blocks(p.block_frames, rgb=encoder.reads_rgb, instance=fs.has_instance)
    n_blocks = -(-fs.n_frames // p.block_frames)
    if progress is not None:
        blocks = progress(blocks, n_blocks, "fusing")
    fused_frames = pixels = 0
    with torch.inference_mode():
        for block in blocks:
            ok = usable[block.start : block.start + len(block)]
            if not ok.any():
                continue
            sel = slice(None) if ok.all() else ok  # no copies of whole blocks
            depth = block.depth_m()[sel]
            dense = encoder.encode_images(block.rgb[sel], depth_m=depth,
                                          instance=None if block.instance is None else block.instance[sel])
            depth_f = dense.resample_depth(depth)
            pts = locate_block(lattice, depth_f, dense.valid.numpy(), poses[block.start : block.start + len(block)][ok],
                               dense.intrinsics(fs.intrinsics), depth_min_m=p.depth_min_m, depth_max_m=p.depth_max_m,
                               max_depth_jump=p.max_depth_jump)
            acc.add(pts, dense, point_weights(pts.dist_m, sigma))
            fused_frames += int(ok.sum())
            pixels += pts.n_fused
    voxels = None
    if kind.fuses_voxels:
        voxels = acc.result()
        cells = voxels.top_down()
        if not p.cfmap_voxels:
            voxels = None
    else:
        cells = acc.result()
    n_seen = len(cells.cell)
    from pipeline.recon import FREE

    cells, n_filled = fill_unseen(cells, recon.grid, recon.occupancy != FREE, p.fill_radius_m)
    if len(cells.cell) == 0:
        raise StageError(f"{frames_path}: no pixel fell inside the grid and height band; nothing to map "
                         f"(check maps.depth_* / maps.*_height_m and the recon grid)")
    identity = encoder.identity()
    write_map(out_path, {**attrs, "encoder": identity, "weighting": {"sigma_m": sigma},
                         "frames": {"n_frames": fs.n_frames, "fused": fused_frames},
                         "points_fused": int(acc.points_fused), "pixels_in_band": int(pixels),
                         "cells_observed": n_seen, "cells_filled": n_filled, "fill_radius_m": p.fill_radius_m},
              recon.grid, lattice, cells.to_store(), tile_cells=p.tile_cells,
              voxels=None if voxels is None else voxels.to_store(recon.grid))
    return {"frames_fused": fused_frames, "frames_skipped": fs.n_frames - fused_frames, "cells": int(len(cells.cell)), "cells_filled": n_filled,
            "voxels": 0 if voxels is None else int(len(voxels.cell)), "points_fused": int(acc.points_fused),
            "encoder": identity["name"], "diagnostic_encoder": bool(identity.get("diagnostic", False)),
            "observed_area_m2": round(len(cells.cell) * recon.grid.cell_size_m**2, 3)}
