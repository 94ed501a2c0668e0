"""Open-vocabulary semantic maps (VLMap, ConceptFusion): fusion, storage, text queries, pictures.

Modules: :mod:`~pipeline.maps.fusion` (vectorized top-down + sparse voxel fusion and the height
rule), :mod:`~pipeline.maps.build` (the stages' unit of work), :mod:`~pipeline.maps.store` (the
map format, documented there as a tree, its types ``Lattice``, ``MapCells``, ``MapVoxels``, ``MapAttrs``
and the :class:`SemanticMap` reader), :mod:`~pipeline.maps.query` (heatmaps and object candidates),
:mod:`~pipeline.maps.levels` (each cell's best height level: ``query.levels: max``),
:mod:`~pipeline.maps.scoring` (numpy products of the fp16 features), :mod:`~pipeline.maps.render` (PNGs).
"""

__all__ = ["FORMAT_VERSION", "SemanticMap"]


def __getattr__(name: str):
    """``FORMAT_VERSION`` and ``SemanticMap`` of :mod:`pipeline.maps.store`, imported on first use: a map stage's
    config (:mod:`pipeline.maps.config`, read by ``zipon status``) needs neither numpy nor zarr."""
    if name in __all__:
        from pipeline.maps import store

        return getattr(store, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
