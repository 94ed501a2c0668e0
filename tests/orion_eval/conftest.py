"""One tiny simulated scene built once per session with the real stages (oracle encoder for the maps)."""

import pytest

TINY_PARAMS = """\
scenes:
  tiny: {source: simulate}
simulate: {frames: 140, width: 160, height: 120, rooms_min: 3, rooms_max: 3}
reconstruct: {voxel_size_m: 0.05}
encoders: {simulated: oracle, oracle: {out_size: [30, 40]}}
maps: {cfmap_voxels: false}
goals: {max_goals: 8}
routes: {episodes_per_goal: 2}
eval: {workers: 1, seeds: [0, 1]}
"""


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    """``(Workspace, Params)`` of a workspace whose scene 'tiny' has every artifact and manifest."""
    from pipeline.config import load_params
    from pipeline.paths import Workspace
    from pipeline.runner import plan, run_many
    from stages import STAGES

    root = tmp_path_factory.mktemp("eval_ws")
    (root / "params.yaml").write_text(TINY_PARAMS)
    ws = Workspace.resolve(root / "params.yaml", data_dir=root / "data", manifests_dir=root / "manifests")
    params = load_params(ws.params_path)
    outcomes = run_many(ws, params, STAGES, plan(STAGES, params, ["tiny"]), show_progress=False)
    failed = [o for o in outcomes if o.status not in ("ran", "skipped")]
    assert not failed, failed[0].error
    return ws, params
