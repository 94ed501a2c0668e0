"""The vlmap and cfmap stages end to end on the ray-cast box room with the oracle encoder."""

import numpy as np
import pytest

from pipeline.config import parse_params
from pipeline.maps.evaluate import evaluate_map, sample_poses
from pipeline.maps.query import open_query, query_map
from pipeline.maps.store import SemanticMap
from pipeline.paths import Workspace
from pipeline.recon import Recon
from pipeline.runner import StageContext
from stages import STAGES
from stages.cfmap import run as run_cfmap
from stages.reconstruct import reconstruct
from stages.vlmap import run as run_vlmap
from tests.fixtures.recon_scenes import write_box_room_frames


def _params(**oracle):
    return parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 100, "cols": 160},
                         "encoders": {"simulated": "oracle", "oracle": {"out_size": [60, 80], **oracle}}})


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("maps")
    frames, gt = write_box_room_frames(tmp / "frames.zarr", n_frames=48)
    params = _params()
    reconstruct(frames, tmp / "recon.zarr", tmp / "recon_mesh.ply", tmp / "recon_points.ply", params.reconstruct,
                params.grid)
    ws = Workspace(root=tmp, data_dir=tmp / "data", manifests_dir=tmp / "manifests")
    out, summaries = tmp / "out", {}
    for stage, run in (("vlmap", run_vlmap), ("cfmap", run_cfmap)):
        outputs = {stage: out / f"{stage}.zarr"}
        ctx = StageContext("box", stage, params, ws, {"frames": frames, "recon": tmp / "recon.zarr"}, outputs,
                           "blake2b:test", False)
        summaries[stage] = run(ctx)
    return tmp, out, frames, gt, params, summaries


def test_registered():
    for name in ("vlmap", "cfmap"):
        spec = STAGES[name]
        assert spec.inputs == ("frames", "recon") and spec.outputs == (name,)
        assert spec.params == ("maps", "encoders", "grid") and "pipeline.encoders" in spec.code


def test_artifacts_describe_themselves(built):
    tmp, out, frames, gt, params, summaries = built
    for name in ("vlmap", "cfmap"):
        m = SemanticMap(out / f"{name}.zarr")
        assert m.artifact == name and m.attrs["stage"] == name and m.attrs["params_digest"] == "blake2b:test"
        assert m.encoder["name"] == "oracle" and m.encoder["diagnostic"] is True and m.dim == 512
        assert m.grid == Recon(tmp / "recon.zarr").grid
        assert m.attrs["frames"] == {"n_frames": 48, "fused": 48}
        assert summaries[name]["frames_fused"] == 48 and summaries[name]["cells"] == m.n_cells
    vl, cf = SemanticMap(out / "vlmap.zarr"), SemanticMap(out / "cfmap.zarr")
    assert vl.voxels() is None and len(cf.voxels()["key"]) == summaries["cfmap"]["voxels"] > cf.n_cells
    # the same height rule on both maps: the same cells with the same top levels
    assert np.array_equal(vl.cell, cf.cell) and np.array_equal(vl.level, cf.level)
    assert cf.attrs["weighting"] == {"sigma_m": 0.6} and vl.attrs["weighting"] == {"sigma_m": None}


@pytest.mark.parametrize("name", ["vlmap", "cfmap"])
def test_queries_find_every_class(built, name):
    tmp, out, frames, gt, params, _ = built
    mq = open_query(out / f"{name}.zarr", params, recon_path=tmp / "recon.zarr", frames_path=frames)
    poses = sample_poses(Recon(tmp / "recon.zarr").navigable, mq.grid, 6, seed=1)
    figures = evaluate_map(mq, gt, poses)
    print(name, figures)
    assert figures["queries"] == 3 * 7
    assert figures["hit_rate"] >= 0.95
    # 60x80 features of 160x120 frames: the table top (0.75 m, camera 0.88 m) is seen only at grazing angles
    assert all(v["iou"] >= 0.4 for v in figures["per_class"].values()) and figures["mean_iou"] >= 0.55
    r = query_map(out / f"{name}.zarr", tmp / "recon.zarr", "red box", (1.0, 1.0, 0.0), params=params,
                  frames_path=frames)
    top = r.candidates[0]
    assert top.gt_class == "box" and top.gt_instance == 3 and top.approach_xy is not None
    assert r.to_json()["candidates"][0]["gt_class"] == "box"
