"""Reconstruction: TSDF fusion of a frame store and the top-down grids every later stage reads.

Modules: :mod:`~pipeline.recon.tsdf` (fusion, extraction), :mod:`~pipeline.recon.grids` (floor,
occupancy, navigable, colour, height), :mod:`~pipeline.recon.refine` (optional pose refinement),
:mod:`~pipeline.recon.store` (the ``recon.zarr`` format, documented there as a tree, and the
:class:`Recon` reader), :mod:`~pipeline.recon.build` (the reconstruct stage's work:
:func:`~pipeline.recon.build.reconstruct`),
:mod:`~pipeline.recon.evaluate` (held-out depth error),
:mod:`~pipeline.recon.render` (north-up PNGs).
"""

from pipeline.recon.store import ARTIFACT, FORMAT_VERSION, FREE, OCCUPANCY_CODES, OCCUPIED, UNKNOWN, Grids, Recon

__all__ = ["ARTIFACT", "FORMAT_VERSION", "FREE", "Grids", "OCCUPANCY_CODES", "OCCUPIED", "Recon", "UNKNOWN"]
