"""Stage ``ingest``: a scene's raw logs or dataset folders (one, or several read in order) -> ``frames.zarr``.

The work (reader, time matching, depth range, z-up world, the matching report) is
:func:`pipeline.readers.ingest.ingest`; this module holds the stage's config and entry point.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.config import IngestParams, Params
from pipeline.stageconfig import StageConfig
from pipeline.engine.stagegraph import scene_sources

if TYPE_CHECKING:
    from pipeline.engine.runner import StageContext


class Config(StageConfig):
    """The ``ingest`` section and the scene's reader (``scenes.<scene>.format``). The source path is not part
    of it: the source's content digest is the stage's input, so moving a dataset folder rebuilds nothing."""

    ingest: IngestParams
    format: str

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        return ["ingest", f"scenes.{scene}.format"]

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "Config":
        return cls(ingest=params.ingest, format=params.scenes[scene].format)


def run(ctx: StageContext) -> dict:
    """Read the scene's raw logs (``ctx.inputs['source']``, then ``source_2``, ... in order:
    ``scenes.<scene>.sources``) into ``ctx.outputs['frames']``; returns the matching summary."""
    from pipeline.readers.ingest import ingest  # here: the readers' imports (ROS, scipy) cost every `zipon status`

    return ingest(scene_sources(ctx.inputs), ctx.outputs["frames"], ctx.config.ingest, ctx.config.format,
                  params_digest=ctx.params_digest, label=ctx.workspace.relative, log=ctx.log, progress=ctx.progress,
                  digests=ctx.array_digests("frames"))
