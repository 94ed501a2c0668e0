"""The stage registry: one module per stage, declared once here.

``zipon run`` builds the DAG from these specs; ``dvc.yaml`` declares the same stages and a test
checks they agree.
"""

from __future__ import annotations

from pipeline.runner import SOURCE, StageSpec

STAGES: dict[str, StageSpec] = {
    spec.name: spec
    for spec in (
        StageSpec(
            name="simulate",
            entry="stages.simulate:run",
            inputs=(),
            outputs=("raw_log",),
            params=("simulate", "scene"),
            code=("stages.simulate", "pipeline.sim", "pipeline.ros2", "pipeline.scene_gt"),
            simulated_only=True,
            description="procedural indoor scene rendered along an exploration trajectory -> ROS 2 MCAP log",
        ),
        StageSpec(
            name="ingest",
            entry="stages.ingest:run",
            inputs=(SOURCE,),
            outputs=("frames",),
            params=("ingest", "scene"),
            code=("stages.ingest", "pipeline.readers", "pipeline.frames", "pipeline.ros2", "pipeline.geometry"),
            description="raw log / dataset folder -> frames.zarr (colour, depth, pose matched by time)",
        ),
        StageSpec(
            name="reconstruct",
            entry="stages.reconstruct:run",
            inputs=("frames",),
            outputs=("recon", "recon_mesh", "recon_points"),
            params=("reconstruct", "grid"),
            code=("stages.reconstruct", "pipeline.recon", "pipeline.geometry", "pipeline.frames"),
            description="frames.zarr -> TSDF mesh + points, floor, occupancy/navigable/colour/height grids (recon.zarr)",
        ),
        StageSpec(
            name="vlmap",
            entry="stages.vlmap:run",
            inputs=("frames", "recon"),
            outputs=("vlmap",),
            params=("maps", "encoders", "grid"),
            code=("stages.vlmap", "pipeline.maps", "pipeline.encoders"),
            description="dense pixel features fused into the top-down grid, top-level height rule (vlmap.zarr)",
        ),
        StageSpec(
            name="cfmap",
            entry="stages.cfmap:run",
            inputs=("frames", "recon"),
            outputs=("cfmap",),
            params=("maps", "encoders", "grid"),
            code=("stages.cfmap", "pipeline.maps", "pipeline.encoders"),
            description="ConceptFusion features fused into a sparse voxel map + its top-down projection (cfmap.zarr)",
        ),
        StageSpec(
            name="goals",
            entry="stages.goals:run",
            inputs=("frames", "recon", "recon_mesh"),
            outputs=("goals",),
            params=("goals", "routes", "scene"),
            code=("stages.goals", "pipeline.goals", "pipeline.routes", "pipeline.scene_gt"),
            description="objects (GT, user file or navchat) -> personalized goals with four kinds of feedback (goals.zarr)",
        ),
        StageSpec(
            name="routes",
            entry="stages.routes:run",
            inputs=("goals", "recon", "recon_mesh"),
            outputs=("routes",),
            params=("routes",),
            code=("stages.routes", "pipeline.routes", "pipeline.goals.store", "pipeline.goals.schema",
                  "pipeline.goals.objects"),
            description="goals + navigable grid -> episodes with FMM routes, actions and text, replay-verified (routes.zarr)",
        ),
    )
}
