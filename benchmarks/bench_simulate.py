"""Simulator throughput: ray-cast rendering (batched vs one cast per frame) and end-to-end MCAP writing.

    .venv/bin/python benchmarks/bench_simulate.py            # quick: 48 frames of the demo scene
    .venv/bin/python benchmarks/bench_simulate.py --full     # the paper-scale 1,400-frame scene

Prints one JSON object per line. The reference renders the same frames with one ``cast_rays``
call per frame (the naive loop); "batched" casts ``render_block_frames`` frames per call.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from _common import emit

from pipeline.config import SimulateParams
from pipeline.sim import SceneRaycaster, SimulatedRecording, simulate_scene


def _render_fps(rec: SimulatedRecording, raycaster: SceneRaycaster, block: int, limit: int) -> float:
    poses = rec.frame_T[:limit]
    raycaster.raycast(poses[:1])  # warm-up (BVH build)
    t = time.perf_counter()
    for i in range(0, len(poses), block):
        raycaster.raycast(poses[i:i + block])
    return len(poses) / (time.perf_counter() - t)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--full", action="store_true", help="1,400 frames (the paper's per-scene scale)")
    ap.add_argument("--scene", default="demo")
    args = ap.parse_args()
    frames = 1400 if args.full else 48
    params = SimulateParams(frames=frames)
    t = time.perf_counter()
    rec = SimulatedRecording(args.scene, params)
    plan_s = time.perf_counter() - t
    raycaster = SceneRaycaster(rec.gt, rec.intrinsics)
    n = min(frames, 48)
    ref = _render_fps(rec, raycaster, 1, n)
    batched = _render_fps(rec, raycaster, params.render_block_frames, n)
    emit(bench="render", frames=n, width=params.width, height=params.height,
         reference_one_cast_per_frame_fps=round(ref, 2), batched_fps=round(batched, 2),
         block_frames=params.render_block_frames, speedup=round(batched / ref, 2), plan_seconds=round(plan_s, 3),
         actions=rec.actions)
    with tempfile.TemporaryDirectory() as tmp:
        summary = simulate_scene(args.scene, params, Path(tmp) / "scene.mcap")
    emit(bench="end_to_end", frames=frames, seconds=summary["seconds"], fps=round(frames / summary["seconds"], 2),
         render_seconds=summary["render_seconds"], mcap_bytes=summary["bytes"], objects=summary["objects"],
         rooms=summary["rooms"])


if __name__ == "__main__":
    main()
