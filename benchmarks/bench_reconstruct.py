"""Reconstruction throughput, peak memory and grid time on a simulated scene (one JSON object per line).

    .venv/bin/python benchmarks/bench_reconstruct.py [--frames 1400] [--threads 2] [--workdir DIR]

Simulates ``--frames`` frames of ``--scene`` (cached in ``--workdir``), ingests them, then runs the
reconstruction in fresh worker processes (so peak RSS is per run) on:

- ``every10``: every 10th frame (140 of 1,400), the reference run: the same rooms, a tenth of the frames;
- ``all``: every frame;
- ``--also FRAMES_ZARR ...``: every frame of other stores too (e.g. the 240-frame demo scenes), so
  accuracy is reported per scene;
- ``--sweep N``: N small apartments (``sim_02`` ... , 3 rooms, 160 frames at 160x120: the test
  suite's scene and its siblings), then one ``"run": "sweep"`` line with the mean / min IoU and how
  many scenes reach 0.9 — accuracy across layouts, not one lucky scene.

Peak RSS should follow the TSDF volume (blocks), not the frame count. Each run prints frames/s of
fusion, seconds of extraction and of the grids, peak RSS, the 1-minute load average (the machine
is shared) and, for simulated scenes, IoU of the grids against the simulator's ground truth
(:func:`pipeline.recon.evaluate.grid_accuracy`; the issue asks for >= 0.9).
``OMP_NUM_THREADS`` is set to ``--threads`` in the workers.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from _common import emit, peak_rss_mb

SWEEP_SIM = {"width": 160, "height": 120, "rooms_min": 3, "rooms_max": 3}


def prepare(workdir: Path, scene: str, n_frames: int, small: bool = False) -> Path:
    from pipeline.config import IngestParams, SimulateParams
    from pipeline.readers.ingest import ingest_path
    from pipeline.sim import simulate_scene

    tag = f"{scene}_{n_frames}" + ("_small" if small else "")
    frames = workdir / f"{tag}.zarr"
    if frames.exists():
        return frames
    workdir.mkdir(parents=True, exist_ok=True)
    log = workdir / f"{tag}.mcap"
    t0 = time.perf_counter()
    if not log.exists():
        simulate_scene(scene, SimulateParams(frames=n_frames, **(SWEEP_SIM if small else {})), log)
    t1 = time.perf_counter()
    ingest_path(log, frames, IngestParams(), "mcap", log=lambda m: None)
    emit(step="prepare", scene=scene, frames=n_frames, simulate_s=round(t1 - t0, 1),
         ingest_s=round(time.perf_counter() - t1, 1))
    return frames


def worker(frames_path: Path, every: int, out_dir: Path) -> None:
    from pipeline.config import GridParams, ReconstructParams
    from pipeline.frames import FrameStore
    from pipeline.recon.build import reconstruct
    from pipeline.recon.evaluate import evaluate_grids

    p, grid = ReconstructParams(), GridParams()
    store = FrameStore(frames_path)
    sel = list(range(0, store.n_frames, every))
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    s = reconstruct(frames_path, out_dir / "recon.zarr", out_dir / "recon_mesh.ply", out_dir / "recon_points.ply",
                    p, grid, frames=sel)
    total = time.perf_counter() - t0
    rss_mb = peak_rss_mb()
    acc = evaluate_grids(frames_path, out_dir / "recon.zarr", p) if store.ground_truth else {}
    acc.pop("recon", None)
    emit(**{
        "run": "all" if every == 1 else f"every{every}", "frames": str(frames_path), "frames_fused": s["frames_fused"],
        "threads": int(os.environ.get("OMP_NUM_THREADS", "0")), "fuse_frames_per_s": s["frames_per_s"],
        "fuse_s": s["seconds_fuse"], "extract_s": s["seconds_extract"], "grids_s": s["seconds_grids"],
        "total_s": round(total, 2), "tsdf_blocks": s["tsdf_blocks"], "mesh_triangles": s["mesh_triangles"],
        "peak_rss_mb": round(rss_mb, 1), "rss_mb_per_1k_blocks": round(rss_mb / max(s["tsdf_blocks"], 1) * 1000, 1),
        **acc,
    })


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1400)
    ap.add_argument("--scene", default="sim_00")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/zipon_bench_reconstruct"))
    ap.add_argument("--worker-every", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--also", type=Path, nargs="*", default=[], help="more frames.zarr stores to reconstruct in full")
    ap.add_argument("--sweep", type=int, default=0, help="also N small apartments sim_02.. (3 rooms, 160 frames)")
    ap.add_argument("--frames-path", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out-dir", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker_every is not None:
        worker(args.frames_path, args.worker_every, args.out_dir)
        return
    frames = prepare(args.workdir, args.scene, args.frames)
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    runs = [(frames, 10, args.workdir / "out_every10"), (frames, 1, args.workdir / "out_every1")]
    runs += [(path, 1, args.workdir / f"out_also{k}") for k, path in enumerate(args.also)]
    sweep = [prepare(args.workdir, f"sim_{k + 2:02d}", 160, small=True) for k in range(args.sweep)]
    runs += [(path, 1, args.workdir / f"out_sweep{k}") for k, path in enumerate(sweep)]
    swept = []
    for path, every, out_dir in runs:
        shutil.rmtree(out_dir, ignore_errors=True)
        done = subprocess.run([sys.executable, __file__, "--worker-every", str(every), "--frames-path", str(path),
                               "--out-dir", str(out_dir)], check=True, env=env, stdout=subprocess.PIPE, text=True)
        print(done.stdout, end="", flush=True)
        if path in sweep:
            swept.append(json.loads(done.stdout.strip().splitlines()[-1]))
    if swept:
        summary = {"run": "sweep", "scenes": len(swept)}
        for key in ("iou_occupied", "iou_free", "iou_navigable"):
            values = [r[key] for r in swept]
            summary.update({f"{key}_mean": round(sum(values) / len(values), 4), f"{key}_min": min(values),
                            f"{key}_scenes_ge_0.9": sum(v >= 0.9 for v in values)})
        summary["floor_error_m_max"] = max(r["floor_error_m"] for r in swept)
        emit(**summary)


if __name__ == "__main__":
    main()
