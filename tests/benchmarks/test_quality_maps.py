"""The perception-level segmentation figures of benchmarks/quality_maps.py on the tiny start-to-finish scene."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from pipeline.frames import FrameStore
from pipeline.maps.build import build_map
from pipeline.maps.config import MAP_CONFIGS
from pipeline.maps.query import open_query
from pipeline.store import artifact_attrs

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def quality():
    spec = importlib.util.spec_from_file_location("quality_maps", REPO / "benchmarks" / "quality_maps.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_oracle_map_scores_high_and_simulated_perception_lower(built_scene, quality, tmp_path):
    ws, params = built_scene
    frames, recon = ws.artifact("frames", "tiny"), ws.artifact("recon", "tiny")
    gt = FrameStore(frames).ground_truth
    oracle = quality.segmentation_metrics(open_query(ws.artifact("vlmap", "tiny"), params, recon_path=recon,
                                                     frames_path=frames), gt)
    assert oracle["mAcc"] > 50 and oracle["F-mIoU"] > 50, oracle
    assert set(oracle["per_class"]) == {o.cls for o in gt.objects}
    assert oracle["cells"] == sum(v["cells"] for v in oracle["per_class"].values())

    sim = params.model_copy(update={"encoders": params.encoders.model_copy(update={
        "simulated": "perception",
        "simulated_cf": params.encoders.simulated_cf.model_copy(update={"out_size": (30, 40)})})})
    out = tmp_path / "cfmap.zarr"
    build_map(MAP_CONFIGS["cfmap"].from_params(sim, "tiny"), frames, recon, out, artifact_attrs("cfmap", 1, "cfmap", "t"))
    perceived = quality.segmentation_metrics(open_query(out, sim, recon_path=recon, frames_path=frames), gt)
    assert perceived["mAcc"] < oracle["mAcc"] - 10, (perceived["mAcc"], oracle["mAcc"])
    # per class, what its cells were labelled as instead: labels of the vocabulary, never more than it missed
    vocab = {o.cls for o in gt.objects} | set(quality.BACKGROUND_VOCAB)
    for c, v in perceived["per_class"].items():
        assert set(v["confused_as"]) <= vocab - {c}
        assert sum(v["confused_as"].values()) <= 100 - v["acc"] + 0.5
    assert any(v["confused_as"] for v in perceived["per_class"].values())
