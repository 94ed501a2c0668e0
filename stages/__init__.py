"""The stage registry: one module per stage, declared once here.

Each ``stages/<name>.py`` holds the stage's typed ``Config`` (built from params; exactly what its params
digest covers) and ``run(ctx)``. Its code is the import closure of that module (:mod:`pipeline.engine.codedeps`).
``zipon run`` builds the DAG from these specs; ``dvc.yaml`` declares the same stages and a test
checks they agree.
"""

from __future__ import annotations

from pipeline.engine.stagegraph import SOURCE, StageSpec

STAGES: dict[str, StageSpec] = {
    spec.name: spec
    for spec in (
        StageSpec(
            name="simulate",
            entry="stages.simulate:run",
            inputs=(),
            outputs=("raw_log",),
            simulated_only=True,
            description="procedural indoor scene rendered along an exploration trajectory -> ROS 2 MCAP log",
        ),
        StageSpec(
            name="ingest",
            entry="stages.ingest:run",
            inputs=(SOURCE,),
            outputs=("frames",),
            description="raw log / dataset folder -> frames.zarr (colour, depth, pose matched by time)",
        ),
        StageSpec(
            name="reconstruct",
            entry="stages.reconstruct:run",
            inputs=("frames",),
            outputs=("recon", "recon_mesh", "recon_points"),
            spreads_threads=True,  # open3d's integrate: identical grids, mesh and points on 1 or N threads (test)
            description="frames.zarr -> TSDF mesh + points, floor, occupancy/navigable/colour/height grids (recon.zarr)",
        ),
        StageSpec(
            name="vlmap",
            entry="stages.vlmap:run",
            inputs=("frames", "recon"),
            outputs=("vlmap",),
            description="dense pixel features fused into the top-down grid, top-level height rule (vlmap.zarr)",
        ),
        StageSpec(
            name="cfmap",
            entry="stages.cfmap:run",
            inputs=("frames", "recon"),
            outputs=("cfmap",),
            description="ConceptFusion features fused into a sparse voxel map + its top-down projection (cfmap.zarr)",
        ),
        StageSpec(
            name="goals",
            entry="stages.goals:run",
            inputs=("frames", "recon", "recon_mesh"),
            outputs=("goals",),
            description="objects (GT, user file or navchat) -> personalized goals with four kinds of feedback (goals.zarr)",
        ),
        StageSpec(
            name="routes",
            entry="stages.routes:run",
            inputs=("goals", "recon", "recon_mesh"),
            outputs=("routes",),
            description="goals + navigable grid -> episodes with FMM routes, actions and text, replay-verified (routes.zarr)",
        ),
    )
}
