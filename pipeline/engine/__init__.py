"""The run machinery: what a contributor to a reader, an encoder, a map or a stage never needs to read.

Modules: :mod:`~pipeline.engine.runner` (runs stages, serially or over dask), :mod:`~pipeline.engine.stagegraph`
(the stages' DAG and staleness), :mod:`~pipeline.engine.codedeps` (a stage's code closure and digest),
:mod:`~pipeline.engine.publication` (publishing a stage's outputs with their manifest as one set),
:mod:`~pipeline.engine.manifest` (manifests), :mod:`~pipeline.engine.locks` (per-scene locks),
:mod:`~pipeline.engine.fsroot` (local and object-store data roots), :mod:`~pipeline.engine.dvcfile` (``dvc.yaml``, the
stages' code identities and ``dvc.lock``), :mod:`~pipeline.engine.verify` (``zipon verify``), :mod:`~pipeline.engine.process` (worker tuning).
"""
