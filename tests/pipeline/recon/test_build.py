"""The reconstruct stage's work (pipeline.recon.build) on the real TUM sample: bad floors input fails whole."""

import pytest

from pipeline.config import GridParams, ReconstructParams
from pipeline.errors import ConfigError, StageError
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from tests.fixtures.real_data import TUM_RPY
from tests.fixtures.recon_scenes import write_tum_frames


@pytest.fixture(scope="module")
def tum(tmp_path_factory):
    return write_tum_frames(tmp_path_factory.mktemp("tum") / "frames.zarr", TUM_RPY)


def _outputs(tmp_path):
    return tmp_path / "recon.zarr", tmp_path / "mesh.ply", tmp_path / "points.ply"


def test_a_single_frame_is_a_clear_error_and_nothing_is_written(tum, tmp_path):
    recon, mesh, points = _outputs(tmp_path)
    with pytest.raises(StageError, match="a single frame was fused \\(frame 3\\).*reconstruct.min_weight"):
        reconstruct(tum, recon, mesh, points, ReconstructParams(), GridParams(), frames=[3])
    assert not recon.exists()


def test_a_pinned_floor_with_no_surface_is_one_line_naming_the_key(tum, tmp_path):
    recon, mesh, points = _outputs(tmp_path)
    p = ReconstructParams(floors=[{"floor_z_m": 0.04}, {"floor_z_m": 2.5}])
    with pytest.raises(ConfigError) as err:
        reconstruct(tum, recon, mesh, points, p, GridParams())
    assert str(err.value).startswith("reconstruct.floors[1].floor_z_m: no floor at 2.50 m") and "\n" not in str(err.value)
    assert not recon.exists()


def test_one_pinned_floor_is_the_single_floor_store(tum, tmp_path):
    recon, mesh, points = _outputs(tmp_path)
    summary = reconstruct(tum, recon, mesh, points, ReconstructParams(floors=[{"floor_z_m": 0.044, "name": "lab"}]),
                          GridParams())
    store = Recon(recon)
    assert store.attrs["format_version"] == 1 and store.floor_z == 0.044 and store.meta.floor_estimated is False
    assert [(f.name, f.source) for f in store.floors] == [("lab", "pinned")]
    assert summary["floors"][0]["name"] == "lab" and summary["floors"][0]["source"] == "pinned"
