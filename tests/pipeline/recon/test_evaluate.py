"""Held-out depth error on real TUM RGB-D data (fr1/rpy, first 30 frames)."""


import pytest

from pipeline.config import ReconstructParams
from pipeline.errors import InputDataError
from pipeline.recon.evaluate import evaluate_grids, evaluate_holdout, holdout_indices
from tests.fixtures.recon_scenes import write_tum_frames
from tests.fixtures.real_data import TUM_RPY as TUM



def test_holdout_indices():
    assert holdout_indices(30, 6).tolist() == [3, 9, 15, 21, 27]
    with pytest.raises(InputDataError, match="holdout_every must be at least 2"):
        holdout_indices(30, 1)


def test_real_tum_holdout_depth_error_is_within_3cm(tmp_path):
    frames = write_tum_frames(tmp_path / "tum.zarr", TUM)
    result = evaluate_holdout(frames, ReconstructParams(), holdout_every=6)
    print({k: result[k] for k in ("median_abs_error_m", "p90_abs_error_m", "coverage", "frames_fused")})
    assert result["frames_held_out"] == [3, 9, 15, 21, 27] and result["frames_fused"] == 25
    assert result["median_abs_error_m"] <= 0.03
    assert result["coverage"] > 0.7 and result["pixels"] > 500_000


def test_grid_scores_need_ground_truth(tmp_path):
    frames = write_tum_frames(tmp_path / "tum.zarr", TUM)
    with pytest.raises(InputDataError, match="carry no ground truth") as err:
        evaluate_grids(frames, tmp_path / "recon.zarr")
    assert "attrs.ground_truth" in str(err.value)
