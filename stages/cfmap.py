"""Stage ``cfmap``: ``frames.zarr`` + ``recon.zarr`` -> ``cfmap.zarr`` (ConceptFusion-style map).

Pixel features of ``encoders.cfmap`` (ConceptFusion's global + region CLIP features) fused into
a sparse 3-D voxel map with ConceptFusion's confidence weights exp(-d^2 / 2 sigma^2), and its
top-down projection by the same height rule as the vlmap; format in :mod:`pipeline.maps.store`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.maps.config import CfmapConfig

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext

Config = CfmapConfig  # the cfmap stage's config (pipeline.maps.config.MapConfig)


def run(ctx: StageContext) -> dict:
    # imported here: reading the stage's Config (`zipon status`) needs none of numpy, zarr or the frame store
    from pipeline.engine.codedeps import code_digest
    from pipeline.maps.build import build_map
    from pipeline.maps.store import FORMAT_VERSION
    from pipeline.store import artifact_attrs

    cfg = ctx.config
    ctx.log(f"fusing {ctx.inputs['frames'].name} into a sparse voxel map on {ctx.inputs['recon'].name}'s grid "
            f"(encoder {cfg.encoder})")
    attrs = artifact_attrs("cfmap", FORMAT_VERSION, "cfmap", ctx.params_digest)
    fold = ctx.workspace.fold(ctx.scene, ctx.stage) if ctx.runtime.map_fold_cache else None
    return build_map(cfg, ctx.inputs["frames"], ctx.inputs["recon"], ctx.outputs["cfmap"], attrs, runtime=ctx.runtime,
                     progress=lambda it, n, d: ctx.progress(it, total=n, description=d), map_ordered=ctx.map_ordered,
                     fold_path=fold, fold_key={"params": ctx.params_digest, "code": code_digest(__name__)}, log=ctx.log)
