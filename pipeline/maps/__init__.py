"""Open-vocabulary semantic maps (VLMap, ConceptFusion): fusion, storage, text queries, pictures.

Modules: :mod:`~pipeline.maps.fusion` (vectorized top-down + sparse voxel fusion and the height
rule), :mod:`~pipeline.maps.build` (the stages' unit of work), :mod:`~pipeline.maps.store` (the
map format, documented there as a tree, and the :class:`SemanticMap` reader),
:mod:`~pipeline.maps.query` (heatmaps and object candidates), :mod:`~pipeline.maps.render` (PNGs).
"""

from pipeline.maps.store import FORMAT_VERSION, SemanticMap

__all__ = ["FORMAT_VERSION", "SemanticMap"]
