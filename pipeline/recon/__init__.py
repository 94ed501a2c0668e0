"""Reconstruction: TSDF fusion of a frame store and the top-down grids every later stage reads.

Modules: :mod:`~pipeline.recon.tsdf` (fusion, extraction), :mod:`~pipeline.recon.floors` (the floors, from the
surface and the camera heights), :mod:`~pipeline.recon.grids` (each floor's occupancy, navigable, colour, height),
:mod:`~pipeline.recon.stairs` (stairs and ramps joining floors), :mod:`~pipeline.recon.refine` (optional pose refinement),
:mod:`~pipeline.recon.store` (the ``recon.zarr`` format, documented there as a tree, and the
:class:`Recon` reader), :mod:`~pipeline.recon.build` (the reconstruct stage's work:
:func:`~pipeline.recon.build.reconstruct`),
:mod:`~pipeline.recon.evaluate` (held-out depth error),
:mod:`~pipeline.recon.render` (north-up PNGs).
"""

from pipeline.recon.store import (ARTIFACT, FORMAT_VERSION, FREE, OCCUPANCY_CODES, OCCUPIED, UNKNOWN, Floor, FloorGrids,
                                  Grids, Recon, StairLink)

__all__ = ["ARTIFACT", "FORMAT_VERSION", "FREE", "Floor", "FloorGrids", "Grids", "OCCUPANCY_CODES", "OCCUPIED", "Recon",
           "StairLink", "UNKNOWN"]
