"""Byte-identical reruns: the same raw inputs give the same digest for every artifact, whatever the scheduler.

Two tiny simulated apartments are built from scratch twice, in two data roots: once in one process
('sync'), once by two dask worker processes ('processes', the two scenes at once, each map's three chunks
of 8 frames spread over both workers); then the
reconstruction of the first root is forced again in threads (both scenes fused at once in one process,
open3d's hash map filled by racing threads). Every artifact of every stage must keep its digest
(open3d hands its voxels and points out in a different order each run; see pipeline.recon.tsdf).
"""

import os
from pathlib import Path

import pytest

from zipon.cli import main
from pipeline.paths import Workspace
from pipeline.store import content_digest
from stages import STAGES

SCENES = ("sim_00", "sim_01")
PARAMS = """\
scenes:
  sim_00: {source: simulate}
  sim_01: {source: simulate}
run: {scheduler: sync, workers: 2}
grid: {rows: 200, cols: 200, cell_size_m: 0.05}
simulate: {frames: 24, width: 96, height: 72, rooms_min: 2, rooms_max: 2}
encoders: {simulated: oracle, oracle: {out_size: [30, 40]}}
goals: {max_goals: 4}
routes: {episodes_per_goal: 1}
reconstruct: {voxel_size_m: 0.05}
maps: {chunk_frames: 8}
"""


def build(root: Path, *args: str, params: str = PARAMS, scenes: tuple[str, ...] = SCENES) -> dict[str, str]:
    """``zipon run ARGS`` in the workspace at ``root``; the content digest of every artifact, by scene/name."""
    root.mkdir(exist_ok=True)
    (root / "params.yaml").write_text(params)
    ws = Workspace.resolve(root / "params.yaml", data_dir=root / "data", manifests_dir=root / "manifests")
    code = main(["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), "run", *args])
    assert code == 0, f"zipon run {' '.join(args)} failed"
    names = sorted({name for spec in STAGES.values() for name in spec.outputs})
    return {f"{scene}/{name}": content_digest(ws.artifact(name, scene)) for scene in scenes for name in names
            if ws.artifact(name, scene).exists()}


def stages_at_once_in_one_worker(root: Path) -> list[tuple[str, str]]:
    """Pairs of stages whose manifests say they ran in the same worker process at overlapping times (``timing``:
    pid, start to the millisecond, wall seconds): a worker holding a seceded map stage must not start another
    stage beside it (pipeline.engine.runner.STAGE_SLOT)."""
    import json
    from datetime import datetime

    spans = []
    for m in sorted(root.glob("manifests/*/*.json")):
        t = json.loads(m.read_text())["timing"]
        start = datetime.fromisoformat(t["started"]).timestamp()
        spans.append((t["pid"], start, start + t["seconds"], f"{m.parent.name}/{m.stem}"))
    assert len({pid for pid, *_ in spans}) == 2  # both workers ran stages
    # 5 ms of slack: 'started' is taken just after the stage's staleness check, 'seconds' ends just before publish
    return [(a[3], b[3]) for i, a in enumerate(spans) for b in spans[i + 1:]
            if a[0] == b[0] and a[1] < b[2] - 0.005 and b[1] < a[2] - 0.005]


@pytest.mark.slow
def test_every_artifact_has_the_same_digest_in_one_process_and_in_two_worker_processes(tmp_path):
    single = build(tmp_path / "sync")
    assert len(single) == len(SCENES) * len({n for s in STAGES.values() for n in s.outputs})
    workers = build(tmp_path / "processes", "--scheduler", "processes")
    assert {k: v for k, v in workers.items() if v != single[k]} == {}
    assert stages_at_once_in_one_worker(tmp_path / "processes") == []
    forced = build(tmp_path / "sync", "--stage", "reconstruct", "--force", "--scheduler", "threads")
    assert {k: v for k, v in forced.items() if v != single[k]} == {}


# one scene, keyframes chosen by reconstruct and the only frames the maps fuse; thresholds wide enough that the
# walk's small steps are passed over
KEYFRAME_PARAMS = PARAMS.replace("  sim_01: {source: simulate}\n", "").replace(
    "reconstruct: {voxel_size_m: 0.05}",
    "reconstruct: {voxel_size_m: 0.05, keyframes: true, keyframe_translation_m: 1.0, keyframe_rotation_deg: 60.0,"
    " keyframe_novel_fraction: 0.6}").replace("maps: {chunk_frames: 8}", "maps: {chunk_frames: 8, keyframes_only: true}")


def native_threads(root: Path, scene: str = "sim_00") -> dict[str, int]:
    """stage -> the native threads it ran with (its manifest's ``timing.native_threads``)."""
    import json

    return {m.stem: json.loads(m.read_text())["timing"]["native_threads"]
            for m in (root / "manifests" / scene).glob("*.json")}


@pytest.mark.slow
def test_keyframe_maps_have_the_same_digest_in_one_process_and_in_two_worker_processes(tmp_path):
    """Also: the scene alone on 2 workers reconstructs on both workers' threads (open3d on 2 threads, against 1 in
    the 1-worker build) and every artifact keeps its digest."""
    from pipeline.maps.store import SemanticMap
    from pipeline.recon import Recon

    stages = [arg for stage in ("simulate", "ingest", "reconstruct", "vlmap", "cfmap") for arg in ("--stage", stage)]
    single = build(tmp_path / "sync", *stages, params=KEYFRAME_PARAMS.replace("workers: 2", "workers: 1"),
                   scenes=("sim_00",))
    assert set(native_threads(tmp_path / "sync").values()) == {1}
    assert set(single) == {f"sim_00/{name}" for name in ("raw_log", "frames", "recon", "recon_mesh", "recon_points",
                                                           "vlmap", "cfmap")}
    recon = Recon(tmp_path / "sync" / "data" / "artifacts" / "sim_00" / "recon.zarr")
    assert 0 < recon.fused.sum() < len(recon.fused), "the rule kept every frame: the test would prove nothing"
    for kind in ("vlmap", "cfmap"):  # the maps fused the keyframes only (each has depth in the band here)
        frames = SemanticMap(tmp_path / "sync" / "data" / "artifacts" / "sim_00" / f"{kind}.zarr").meta.frames
        assert (frames.fused, frames.keyframes_only) == (recon.fused.sum(), True)
    workers = build(tmp_path / "processes", *stages, "--scheduler", "processes", params=KEYFRAME_PARAMS,
                    scenes=("sim_00",))
    assert {k: v for k, v in workers.items() if v != single[k]} == {}
    threads = native_threads(tmp_path / "processes")
    assert threads == {**dict.fromkeys(threads, 1), "reconstruct": min(2, os.cpu_count() or 1)}
