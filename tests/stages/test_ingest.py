"""Stage ``ingest`` through the runner: publication, manifest summary, deterministic digests."""

from __future__ import annotations

import json

import numpy as np

from pipeline.paramsfile import parse_params
from pipeline.frames import FrameStore
from pipeline.paths import Workspace
from pipeline.readers.ingest import ingest_path
from pipeline.engine.runner import run_stage
from pipeline.store import content_digest
from stages import STAGES
from tests.fixtures.raw_datasets import make_recording, write_mcap


def test_runner_ingests_a_recorded_log(tmp_path):
    rec = make_recording(10)
    write_mcap(tmp_path / "robot.mcap", rec, transport="compressed", pose_kind="tf", pose_rate_factor=3)
    params = parse_params({"scenes": {"lab": {"source": "robot.mcap"}}, "ingest": {"block_frames": 4}})
    ws = Workspace(root=tmp_path, data_dir=tmp_path / "data", manifests_dir=tmp_path / "manifests")
    outcome = run_stage(ws, params, STAGES, "lab", "ingest", show_progress=False)
    assert outcome.status == "ran", outcome.error
    assert outcome.summary["matched_frames"] == 10
    fs = FrameStore(ws.artifact("frames", "lab"))
    assert np.array_equal(fs.group["rgb"][:], rec.rgb) and np.array_equal(fs.group["instance"][:], rec.instance)
    assert np.abs(fs.poses() - rec.poses).max() < 1e-9
    assert fs.attrs["provenance"]["source"] == "./robot.mcap"
    assert fs.attrs["matching"] == json.loads(json.dumps(outcome.summary))
    man = json.loads(ws.manifest("lab", "ingest").read_text())
    assert man["summary"]["matched_frames"] == 10
    assert run_stage(ws, params, STAGES, "lab", "ingest", show_progress=False).status == "skipped"


def test_same_inputs_same_digest(tmp_path):
    from pipeline.config import IngestParams

    rec = make_recording(6)
    log = write_mcap(tmp_path / "a.mcap", rec)
    digests = []
    for k in range(2):
        out = tmp_path / f"f{k}.zarr"
        ingest_path(log, out, IngestParams(block_frames=4), log=lambda m: None)
        digests.append(content_digest(out))
    assert digests[0] == digests[1]
