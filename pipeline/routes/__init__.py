"""The routes stage: episodes and their reference routes, over the navigation toolkit :mod:`pipeline.nav`.

Modules: :mod:`~pipeline.routes.episodes` (seeded episodes), :mod:`~pipeline.routes.store` (``routes.zarr`` format
tree and the :class:`Routes` reader), :mod:`~pipeline.routes.build` (the routes stage's work:
:func:`~pipeline.routes.build.build_routes`).
"""
