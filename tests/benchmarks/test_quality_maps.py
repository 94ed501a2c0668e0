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


def test_maps_option_scores_only_the_named_maps_against_their_published_rows(built_scene, quality):
    """``--maps cfmap`` scores the workspace's cfmap alone; each simulated model is set against a published row, the
    ConceptFusion model against the SAM variant the paper's code runs."""
    from pipeline.encoder_params.perception import PUBLISHED

    ws, _ = built_scene
    rows = quality.workspace_scenes(ws.params_path, 4, [], [], only=["tiny"], maps=("cfmap",))
    assert rows and {r["map"] for r in rows} == {"cfmap"} and {r["scene"] for r in rows} == {"tiny"}
    assert all(0 <= r["mAcc"] <= 100 and 0 <= r["F-mIoU"] <= 100 for r in rows)
    assert set(quality.TARGET.values()) <= set(PUBLISHED)
    assert quality.TARGET["simulated_cf"] == "ConceptFusion + SAM"


def test_an_unknown_map_is_refused_by_name():
    import subprocess
    import sys

    run = subprocess.run([sys.executable, str(REPO / "benchmarks" / "quality_maps.py"), "--no-fixture", "--maps",
                          "semmap"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert "--maps: invalid choice: 'semmap' (choose from" in run.stderr and "cfmap" in run.stderr, run.stderr
