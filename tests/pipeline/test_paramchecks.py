"""Cross-field checks of params at load: each error names the keys and what would work; good params pass."""

from __future__ import annotations

import pytest

from pipeline.errors import ConfigError
from pipeline.paramchecks import check_params
from pipeline.paramsfile import parse_params

SIM = {"scenes": {"tiny": {"source": "simulate"}}}
GB = 1 << 30


def params(**sections):
    return parse_params({**SIM, **sections})


def test_defaults_pass():
    check_params(params(), "params.yaml", memory=8 * GB)


@pytest.mark.parametrize("sections, words", [
    ({"reconstruct": {"voxel_size_m": 1e-9}}, "reconstruct.voxel_size_m: 1e-09 m is below 0.001 m"),
    ({"reconstruct": {"voxel_size_m": 0.03}}, "grid.cell_size_m (0.05) must be a whole multiple of "
                                               "reconstruct.voxel_size_m (0.03)"),
    ({"reconstruct": {"voxel_size_m": 0.001, "sdf_trunc_m": 0.08}, "grid": {"cell_size_m": 0.1}},
     "gives 100 voxels per edge"),
    ({"grid": {"rows": 10**7}}, "grid.rows: 10,000,000 cells of 0.05 m span 500,000 m"),
    ({"grid": {"rows": 100_000, "cols": 100_000}}, "grid.rows x grid.cols: 100,000 x 100,000 cells need about"),
    ({"simulate": {"width": 10**6}}, "simulate.width: 1,000,000 pixels (expected at most 16,384)"),
    ({"simulate": {"width": 8000, "height": 8000, "render_block_frames": 64}}, "simulate.render_block_frames x"),
    ({"simulate": {"seed": 10**30}}, "simulate.seed: an integer of 31 digits is out of range"),
])
def test_values_that_cannot_work_together(sections, words):
    with pytest.raises(ConfigError) as err:
        check_params(_unchecked({**SIM, **sections}), "params.yaml", memory=8 * GB)
    assert words in str(err.value) and str(err.value).startswith("params.yaml: "), str(err.value)


def _unchecked(raw):
    from pipeline.config import Params

    return Params.model_validate(raw)


def test_the_check_runs_at_load_naming_the_file():
    with pytest.raises(ConfigError, match=r"^params.yaml: simulate.width: 1,000,000 pixels"):
        parse_params({**SIM, "simulate": {"width": 10**6}}, origin="params.yaml")


def test_a_real_scene_skips_the_simulator_bounds():
    real = {"scenes": {"lab": {"source": "raw/lab.mcap"}}, "simulate": {"width": 10**6}}
    parse_params(real)  # simulate.* is not used by any scene
