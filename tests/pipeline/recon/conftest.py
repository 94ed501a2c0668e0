"""A reconstructed two-storey house shared by the floor, stair and render tests (one build per session)."""

import pytest

from pipeline.config import GridParams, ReconstructParams
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from tests.fixtures.recon_scenes import write_two_storey_frames


@pytest.fixture(scope="session")
def house(tmp_path_factory):
    """``(summary, Recon, GTScene)`` of :func:`write_two_storey_frames` reconstructed on a 160 x 200 grid."""
    tmp = tmp_path_factory.mktemp("house")
    frames, gt = write_two_storey_frames(tmp / "frames.zarr")
    summary = reconstruct(frames, tmp / "recon.zarr", tmp / "mesh.ply", tmp / "points.ply", ReconstructParams(),
                          GridParams(rows=160, cols=200))
    return summary, Recon(tmp / "recon.zarr"), gt
