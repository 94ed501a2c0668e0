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
    )
}
