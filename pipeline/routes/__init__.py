"""Geodesic routes, discrete actions, procedural text, episodes and replay verification.

Modules: :mod:`~pipeline.routes.fmm` (FMM fields and shortest paths), :mod:`~pipeline.routes.actions`
(15 deg / 0.25 m actions, navchat's text rules, :func:`procedural_instruction` from any pose),
:mod:`~pipeline.routes.verify` (replay), :mod:`~pipeline.routes.episodes` (seeded episodes),
:mod:`~pipeline.routes.store` (``routes.zarr`` format tree and the :class:`Routes` reader),
:mod:`~pipeline.routes.build` (the routes stage's work: :func:`~pipeline.routes.build.build_routes`).
"""
