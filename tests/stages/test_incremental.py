"""A scene of several raw logs (``scenes.<scene>.sources``) through the runner: appending a log re-ingests and
re-reconstructs the scene, and the map stage fuses only the appended frames when the grid centre and floor are
pinned; the map equals one built from scratch. Plus the config and ingest errors of a multi-log scene."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from pipeline.paramsfile import parse_params
from pipeline.stageconfig import param_value
from pipeline.frames import FrameStore
from pipeline.geometry import Intrinsics
from pipeline.engine.manifest import Manifest
from pipeline.paths import Workspace
from pipeline.ros2 import Ros2LogWriter
from pipeline.engine.stagegraph import input_digests
from pipeline.engine.runner import run_stage
from stages import STAGES
from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames

T0_NS = 1_700_000_000_000_000_000
FRAME_NS = 100_000_000  # 10 Hz
N_A, N_B, CHUNK = 32, 16, 16  # frames of a.mcap and b.mcap; map chunk
W, H = 64, 48
PARAMS = {"grid": {"rows": 100, "cols": 160, "centre_xy": [3.0, 1.5]},
          "reconstruct": {"floor_z_m": 0.0, "voxel_size_m": 0.05},
          "ingest": {"block_frames": 8}, "maps": {"chunk_frames": CHUNK},
          "encoders": {"vlmap": "oracle", "oracle": {"out_size": [24, 32]}}}


def _write_log(path, gt, rgb, depth, inst, poses, first: int, intr: Intrinsics):
    """Frames ``first, first+1, ...`` stamped at 10 Hz from T0 (the second log continues the first one's clock),
    each with its pose, plus one pose 50 ms after the last frame (poses bracket every frame)."""
    with Ros2LogWriter(path, intrinsics=intr, with_instance=True) as w:
        for i in range(len(poses)):
            stamp = T0_NS + (first + i) * FRAME_NS
            w.write_pose(stamp, poses[i])
            w.write_frame(stamp, rgb[i], depth[i], inst[i])
        w.write_pose(stamp + FRAME_NS // 2, poses[-1])
        w.attach_ground_truth(gt)
    return path


@pytest.fixture(scope="module")
def two_logs(tmp_path_factory):
    """The box room as two logs of one walk: a.mcap (a full tour) and b.mcap (a second, shorter one)."""
    tmp = tmp_path_factory.mktemp("two_logs")
    gt, intr = box_room_gt(), Intrinsics.from_hfov(W, H, 90.0)
    poses = np.concatenate([box_room_poses(N_A), box_room_poses(N_B)])
    rgb, depth, inst = render_frames(gt, poses, intr)
    for name, sl in (("a", slice(0, N_A)), ("b", slice(N_A, N_A + N_B))):
        _write_log(tmp / f"{name}.mcap", gt, rgb[sl], depth[sl], inst[sl], poses[sl], sl.start, intr)
    return tmp, poses, rgb


def _build(tmp, sources: list[str], data: str) -> tuple[Workspace, dict]:
    """ingest -> reconstruct -> vlmap of scene 'box' through the runner; {stage: its manifest}."""
    params = parse_params({"scenes": {"box": {"sources": sources}}, **PARAMS})
    ws = Workspace(root=tmp, data_dir=tmp / data, manifests_dir=tmp / f"{data}-manifests")
    manifests = {}
    for stage in ("ingest", "reconstruct", "vlmap"):
        outcome = run_stage(ws, params, STAGES, "box", stage, show_progress=False)
        assert outcome.status == "ran", outcome.error
        manifests[stage] = Manifest.read(ws.manifest("box", stage))
    return ws, manifests


def test_appending_a_log_fuses_only_its_frames_and_gives_the_map_built_from_scratch(two_logs):
    tmp, poses, rgb = two_logs
    ws, first = _build(tmp, ["a.mcap"], "data")
    assert first["vlmap"].summary["chunks_reused"] == 0 and first["ingest"].summary["matched_frames"] == N_A
    ws, grown = _build(tmp, ["a.mcap", "b.mcap"], "data")  # the same workspace: a second log appended

    n = N_A + N_B
    fs = FrameStore(ws.artifact("frames", "box"))
    assert fs.n_frames == n and np.array_equal(fs.group["rgb"][:], rgb)
    assert np.abs(fs.poses() - poses).max() < 1e-9
    assert np.array_equal(fs.group["stamp"][:], T0_NS + np.arange(n) * FRAME_NS)  # as recorded
    prov = fs.attrs["provenance"]["sources"]
    assert [(p["source"], p["frames"]) for p in prov] == [("./a.mcap", [0, N_A]), ("./b.mcap", [N_A, n])]
    match = grown["ingest"].summary
    assert match["matched_frames"] == n and [s["matched_frames"] for s in match["sources"]] == [N_A, N_B]

    summary = grown["vlmap"].summary  # a's complete chunks come from the fold; b's frames are fused
    assert (summary["chunks"], summary["chunks_reused"], summary["frames_reused"]) == (n // CHUNK, N_A // CHUNK, N_A)
    assert summary["frames_processed"] == N_B

    scratch_ws, scratch = _build(tmp, ["a.mcap", "b.mcap"], "scratch")
    assert scratch["vlmap"].summary["chunks_reused"] == 0
    for stage, artifact in (("ingest", "frames"), ("reconstruct", "recon"), ("vlmap", "vlmap")):
        assert grown[stage].outputs[artifact].digest == scratch[stage].outputs[artifact].digest, stage


def test_a_pinned_grid_centre_ignores_the_surface_seen_and_stays_on_the_voxel_lattice():
    """Unpinned, recon centres the grid on the surface it saw, so a second log's surface moves it (and the map's
    fold is rejected: tests/stages/test_maps.py); pinned, the grid is the same whatever was seen."""
    from pipeline.config import GridParams, ReconstructParams
    from pipeline.recon.grids import place_grid

    rng = np.random.default_rng(3)
    seen_a = np.c_[rng.uniform(0, 4, 2000), rng.uniform(0, 3, 2000), np.zeros(2000)]
    seen_ab = np.r_[seen_a, np.c_[rng.uniform(4, 6, 800), rng.uniform(0, 3, 800), np.zeros(800)]]
    for voxel in (0.05, 0.025):
        p = ReconstructParams(voxel_size_m=voxel, sdf_trunc_m=0.08)
        free = GridParams(rows=100, cols=160)
        assert place_grid(seen_a, free, p) != place_grid(seen_ab, free, p)
        pinned = GridParams(rows=100, cols=160, centre_xy=(3.01, 1.49))
        grid = place_grid(seen_a, pinned, p)
        assert grid == place_grid(seen_ab, pinned, p) == place_grid(seen_a[:10] + 50.0, pinned, p)
        x0, x1, y0, y1 = grid.extent_xy
        assert abs((x0 + x1) / 2 - 3.01) <= voxel and abs((y0 + y1) / 2 - 1.49) <= voxel
        centres = grid.cell_to_world(np.array([[0, 0], [17, 123]])) / voxel
        assert np.allclose(centres, np.round(centres), atol=1e-6)


def test_an_unpinned_centre_leaves_the_digests_of_existing_scenes_as_they_were():
    params = parse_params({"scenes": {"box": {"source": "a.mcap"}}, "grid": {"rows": 100, "cols": 160}})
    assert param_value(params, "grid") == {"rows": 100, "cols": 160, "cell_size_m": 0.05}
    assert param_value(params, "scenes.box") == {"source": "a.mcap", "format": "auto"}


def test_the_source_digest_covers_every_log_in_order(two_logs):
    tmp, _, _ = two_logs
    ws = Workspace(root=tmp, data_dir=tmp / "digests", manifests_dir=tmp / "digests-manifests")

    def digest(scene):
        params = parse_params({"scenes": {"box": scene}, **PARAMS})
        return input_digests(ws, params, STAGES, STAGES["ingest"], "box")["source"]

    one = digest({"source": "a.mcap"})
    assert digest({"sources": ["a.mcap"]}) == one  # the list form of one log is the same input
    assert len({one, digest({"sources": ["a.mcap", "b.mcap"]}), digest({"sources": ["b.mcap", "a.mcap"]})}) == 3


# ----------------------------------------------------------------------------- errors through the CLI

def _cli(tmp_path, scenes: dict, *args, capsys) -> tuple[int, str]:
    from zipon.cli import main

    raw = {"scenes": scenes, **PARAMS}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw))
    code = main(["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", str(tmp_path / "data"),
                 "--manifests-dir", str(tmp_path / "manifests"), *args])
    return code, " ".join(capsys.readouterr().err.split())


def test_source_and_sources_together_are_refused_naming_the_scene(tmp_path, capsys):
    code, err = _cli(tmp_path, {"lab": {"source": "a.mcap", "sources": ["a.mcap", "b.mcap"]}}, "status",
                     capsys=capsys)
    assert code == 1 and "scenes.lab" in err and "either 'source'" in err and "not both" in err


def test_a_second_log_with_other_intrinsics_fails_naming_it(two_logs, tmp_path, capsys):
    tmp, poses, _ = two_logs
    gt, intr = box_room_gt(), Intrinsics.from_hfov(48, 36, 90.0)
    rgb, depth, inst = render_frames(gt, poses[N_A:N_A + 4], intr)
    (tmp_path / "a.mcap").write_bytes((tmp / "a.mcap").read_bytes())
    _write_log(tmp_path / "small.mcap", gt, rgb, depth, inst, poses[N_A:N_A + 4], N_A, intr)
    code, err = _cli(tmp_path, {"lab": {"sources": ["a.mcap", "small.mcap"]}}, "stage", "ingest", "--scene", "lab",
                     capsys=capsys)
    assert code != 0
    assert "file ./small.mcap; field intrinsics: this log has 48x36 fx 24" in err, err
    assert f"first log ./a.mcap has {W}x{H}" in err, err
    assert not (tmp_path / "data" / "artifacts" / "lab" / "frames.zarr").exists()


def test_a_bad_second_log_fails_naming_it(two_logs, tmp_path, capsys):
    tmp, _, _ = two_logs
    (tmp_path / "a.mcap").write_bytes((tmp / "a.mcap").read_bytes())
    (tmp_path / "broken.mcap").write_bytes((tmp / "b.mcap").read_bytes()[:4000])  # cut short
    code, err = _cli(tmp_path, {"lab": {"sources": ["a.mcap", "broken.mcap"]}}, "stage", "ingest", "--scene", "lab",
                     capsys=capsys)
    assert code != 0 and "broken.mcap: not a readable MCAP log" in err, err
    assert not (tmp_path / "data" / "artifacts" / "lab" / "frames.zarr").exists()
    code, err = _cli(tmp_path, {"lab": {"sources": ["a.mcap", "missing.mcap"]}}, "stage", "ingest", "--scene", "lab",
                     capsys=capsys)
    assert code != 0 and "missing.mcap" in err and "scenes.lab.sources" in err, err


def test_dvc_lists_every_log_of_a_scene_as_a_dep_of_its_ingest(two_logs, tmp_path):
    """dvc cannot splice a list into deps: each log is an item key (source, source_2); a scene with fewer logs
    repeats its last one, which dvc takes once."""
    import os
    import subprocess
    import sys

    from pipeline.engine.dvcfile import render_dvc_yaml

    tmp, _, _ = two_logs
    for name in ("a", "b"):
        (tmp_path / f"{name}.mcap").write_bytes((tmp / f"{name}.mcap").read_bytes())
    params = parse_params({"scenes": {"one": {"source": "a.mcap"}, "two": {"sources": ["a.mcap", "b.mcap"]}},
                           **PARAMS})
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params.model_dump(mode="json")))
    ws = Workspace(root=tmp_path, data_dir=tmp_path / "data", manifests_dir=tmp_path / "manifests")
    text = render_dvc_yaml(ws, params, STAGES)
    ingest = yaml.safe_load(text)["stages"]["ingest"]
    assert ingest["foreach"] == {"one": {"source": "a.mcap", "source_2": "a.mcap"},
                                 "two": {"source": "a.mcap", "source_2": "b.mcap"}}
    assert ingest["do"]["deps"][:2] == ["${item.source}", "${item.source_2}"]
    (tmp_path / "dvc.yaml").write_text(text)
    env = {**os.environ, "DVC_NO_ANALYTICS": "1"}
    for cmd in (["git", "init", "-q"], [sys.executable, "-m", "dvc", "init", "-q"]):
        subprocess.run(cmd, cwd=tmp_path, env=env, check=True)
    done = subprocess.run([sys.executable, "-m", "dvc", "status", "ingest"], cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    stages = {b.split(":")[0]: b for b in done.stdout.split("ingest@")[1:]}
    assert "b.mcap" in stages["two"] and "a.mcap" in stages["two"]
    assert "a.mcap" in stages["one"] and "b.mcap" not in stages["one"]
