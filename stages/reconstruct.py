"""Stage ``reconstruct``: ``frames.zarr`` -> ``recon.zarr`` + ``recon_mesh.ply`` + ``recon_points.ply``.

The work (TSDF fusion, mesh and points, floor, top-down grids) is :func:`pipeline.recon.build.reconstruct`;
this module holds the stage's config and entry point.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.config import GridParams, ReconstructParams
from pipeline.stageconfig import StageConfig

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext


class Config(StageConfig):
    """The ``reconstruct`` and ``grid`` sections."""

    reconstruct: ReconstructParams
    grid: GridParams


def run(ctx: StageContext) -> dict:
    from pipeline.recon.build import reconstruct  # here: TSDF and grid imports cost every `zipon status`

    p, grid = ctx.config.reconstruct, ctx.config.grid
    ctx.log(f"fusing {ctx.inputs['frames'].name}: voxel {p.voxel_size_m} m, trunc {p.sdf_trunc_m} m, "
            f"grid {grid.rows}x{grid.cols} at {grid.cell_size_m} m")
    return reconstruct(
        ctx.inputs["frames"], ctx.outputs["recon"], ctx.outputs["recon_mesh"], ctx.outputs["recon_points"], p, grid,
        params_digest=ctx.params_digest, tile_m=ctx.runtime.recon_tile_m, log=ctx.log,
        progress=lambda it, n: ctx.progress(it, total=n, description="fusing"),
    )
