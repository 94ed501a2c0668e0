"""Stage ``vlmap``: ``frames.zarr`` + ``recon.zarr`` -> ``vlmap.zarr`` (VLMaps-style top-down feature map).

Dense pixel features of ``encoders.vlmap`` (LSeg by default; ``encoders.simulated`` for simulated
scenes) fused into recon's top-down grid with the height rule and count weights (VLMaps' mean);
format and rule in :mod:`pipeline.maps.store` / :mod:`pipeline.maps.fusion`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.maps.config import VlmapConfig

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext

Config = VlmapConfig  # the vlmap stage's config (pipeline.maps.config.MapConfig)


def run(ctx: StageContext) -> dict:
    # imported here: reading the stage's Config (`zipon status`) needs none of numpy, zarr or the frame store
    from pipeline.engine.codedeps import code_digest
    from pipeline.maps.build import build_map
    from pipeline.maps.store import FORMAT_VERSION
    from pipeline.store import artifact_attrs

    cfg = ctx.config
    ctx.log(f"fusing {ctx.inputs['frames'].name} into {ctx.inputs['recon'].name}'s grid (encoder {cfg.encoder})")
    attrs = artifact_attrs("vlmap", FORMAT_VERSION, "vlmap", ctx.params_digest)
    fold = ctx.workspace.fold(ctx.scene, ctx.stage) if ctx.runtime.map_fold_cache else None
    return build_map(cfg, ctx.inputs["frames"], ctx.inputs["recon"], ctx.outputs["vlmap"], attrs, runtime=ctx.runtime,
                     progress=lambda it, n, d: ctx.progress(it, total=n, description=d), map_ordered=ctx.map_ordered,
                     fold_path=fold, fold_key={"params": ctx.params_digest, "code": code_digest(__name__)}, log=ctx.log)
