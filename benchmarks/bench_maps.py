"""Semantic map benchmarks: fusion throughput vs a naive per-point loop, query latency, peak memory.

Prints one JSON object per line. Fusion is timed with SYNTHETIC unit features of the stated size
(random, fixed seed) on ray-cast depth of the box-room fixture, so the encoder's cost is excluded;
the time covers back-projection, cell/level assignment and the scatter into the accumulator.

- ``fusion``: frames/s of :class:`TopDownAccumulator` (vlmap) and :class:`VoxelAccumulator` (cfmap)
  at 120x160x512 and 480x640x512, and of our VLMaps-faithful per-point loop
  (:mod:`benchmarks.vlmaps_loop`: per point grid id, range checks, two camera-matrix projections,
  colour/height map, distance weight, (1,D,h,w) feature read, voxel id lookup, 512-d running mean)
  timed on WHOLE frames of the same data; ``speedup_vs_vlmaps_loop`` is the ratio of frames/s. The
  loop's voxels are compared with a VoxelAccumulator fed the same points and VLMaps' weights
  (``voxels_equal``, ``max_abs_diff``). A lean loop (``lean_loop_us_per_point``) is shown for context.
  ``speedup_vs_vlmaps_loop`` compares with OUR re-implementation; with ``--vlmaps-src`` (a checkout of
  github.com/vlmaps/vlmaps) VLMaps' REAL ``create_mobile_base_map`` runs on the same frames too
  (:mod:`benchmarks.vlmaps_real`, encoder stubbed), alternating with our loop, and the line adds both per-point CPU
  costs, ``vlmaps_loop_over_real`` (the calibration of our loop) and ``cpu_speedup_vs_vlmaps_real`` (zipon's fusion
  with its ``result()`` against the real loop, per point, CPU time).
- ``fusion_default_sampling`` (with ``--vlmaps-src``): per FRAME at each method's default sampling on 640x480
  frames: VLMaps' real loop over every 100th valid depth pixel (its ``depth_sample_rate``) vs zipon's fusion of every
  120x160 feature cell.
- ``scores``: one query's ``features @ text`` on a 600x600x512 map: fp32 (the old in-memory copy)
  vs the fp16 features kept by :class:`SemanticMap` (``SemanticMap.dot``), and their memory.
- ``query``: latency of :meth:`MapQuery.query` (median of repeats, warm caches) on a 600x600 map
  with D=512, fully observed and 40% observed, 4 background prompts.
- ``memory``: peak RSS of a child process fusing 140 vs 1,400 frames (the 140 frames cycled), and its
  growth during fusion (after the inputs and the 16-frame block of synthetic features exist).

Run: ``.venv/bin/python benchmarks/bench_maps.py [--quick] [--vlmaps-src /tmp/vlmaps]``; threads: ``--threads 2``
(``--threads 1`` for per-point comparisons with the single-threaded loops).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from _common import emit, peak_rss_mb

from pipeline.geometry import GridSpec, Intrinsics
from pipeline.maps.fusion import (
    Lattice,
    TopDownAccumulator,
    VoxelAccumulator,
    locate_block,
    point_weights,
)


CAMERA_HEIGHT_M, CAMERA_PITCH = 0.88, 0.35  # tests.fixtures.recon_scenes.box_room_poses' defaults


def scene_frames(n: int, width: int, height: int):
    from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames

    gt = box_room_gt()
    intr = Intrinsics.from_hfov(width, height, 90.0)
    poses = box_room_poses(n, CAMERA_HEIGHT_M)
    _, depth_mm, _ = render_frames(gt, poses, intr)
    return depth_mm.astype(np.float32) * 1e-3, poses, intr


def lattice() -> Lattice:
    grid = GridSpec.centered((3.0, 1.5), 600, 600, 0.05)
    return Lattice(grid, 0.0, -0.05, 2.0, 0.1)


def synthetic_features(b: int, h: int, w: int, d: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    f = torch.randn((b, h, w, d), generator=g)
    return torch.nn.functional.normalize(f, dim=-1)


def fuse_vectorized(lat, depth, poses, intr, feats, block: int, cpu: list | None = None
                    ) -> tuple[TopDownAccumulator, float]:
    """Wall seconds (and CPU seconds of this process appended to ``cpu``) of top-down fusion."""
    acc = TopDownAccumulator(lat, feats.shape[-1])
    valid = np.ones(depth.shape, bool)
    t0, c0 = time.perf_counter(), time.process_time()
    for s in range(0, len(depth), block):
        e = min(s + block, len(depth))
        pts = locate_block(lat, depth[s:e], valid[s:e], poses[s:e], intr, depth_min_m=0.1, depth_max_m=5.0)
        acc.add(pts, feats[: e - s])
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    return acc, time.perf_counter() - t0


def fuse_lean(lat, depth, poses, intr, feats, max_points: int) -> tuple[float, int]:
    """A LEAN per-point loop (project, bin, add into a per-cell sum with the top rule): a lower bound on
    the per-point cost of any Python loop, shown for context next to the VLMaps-faithful loop."""
    grid = lat.grid
    cells: dict[int, list] = {}
    n = 0
    t0 = time.perf_counter()
    for b in range(len(depth)):
        R, t = poses[b][:3, :3], poses[b][:3, 3]
        fb = feats[b % len(feats)].numpy()
        for v in range(depth.shape[1]):
            for u in range(depth.shape[2]):
                if n >= max_points:
                    return time.perf_counter() - t0, n
                n += 1
                z = float(depth[b, v, u])
                if not (0.1 <= z <= 5.0):
                    continue
                p = R @ np.array([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z]) + t
                col = int(np.floor((p[0] - grid.origin_xy[0]) / grid.cell_size_m))
                row = int(np.floor((grid.origin_xy[1] - p[1]) / grid.cell_size_m))
                level = int(np.floor((p[2] - lat.floor_z - lat.min_height_m) / lat.level_height_m))
                if not (0 <= row < grid.rows and 0 <= col < grid.cols and 0 <= level < lat.levels):
                    continue
                key = row * grid.cols + col
                entry = cells.get(key)
                if entry is None or level > entry[0]:
                    cells[key] = [level, fb[v, u].astype(np.float32).copy(), 1.0]
                elif level == entry[0]:
                    entry[1] += fb[v, u]
                    entry[2] += 1.0
    return time.perf_counter() - t0, n


def fuse_voxels(lat, depth, poses, intr, feats, block: int, sigma_m: float | None) -> tuple[VoxelAccumulator, float]:
    acc = VoxelAccumulator(lat, feats.shape[-1])
    valid = np.ones(depth.shape, bool)
    t0 = time.perf_counter()
    for s in range(0, len(depth), block):
        e = min(s + block, len(depth))
        pts = locate_block(lat, depth[s:e], valid[s:e], poses[s:e], intr, depth_min_m=0.1, depth_max_m=5.0)
        acc.add(pts, feats[: e - s], point_weights(pts.dist_m, sigma_m))
    return acc, time.perf_counter() - t0


def bench_fusion(h: int, w: int, d: int, n_frames: int, naive_points: int, block: int,
                 vlmaps_src: Path | None = None) -> dict:
    """Vectorized top-down (vlmap) and voxel (cfmap) fusion vs our VLMaps-faithful per-point loop
    (:mod:`benchmarks.vlmaps_loop`) timed on whole frames of the same data, and a lean loop for context. With
    ``vlmaps_src`` (a VLMaps checkout), VLMaps' real loop (:mod:`benchmarks.vlmaps_real`) runs on the same frames,
    alternating with our loop (best of 2 each: the machine may be shared). Returns the emitted fields."""
    from benchmarks.vlmaps_loop import SIGMA_SQ, time_loop

    depth_img, poses, intr_img = scene_frames(n_frames, 2 * w if w < 640 else w, 2 * h if h < 480 else h)
    # features at (h, w): depth resampled the way DenseFeatures.resample_depth does (nearest at cell centres)
    H, W = depth_img.shape[1:]
    rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
    cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
    depth = np.ascontiguousarray(depth_img[:, rows[:, None], cols[None, :]])
    intr = intr_img.scaled(w, h)
    feats = synthetic_features(min(block, n_frames), h, w, d)
    rgb = np.random.default_rng(0).integers(0, 256, (min(block, n_frames), H, W, 3), dtype=np.uint8)
    lat = lattice()
    fuse_vectorized(lat, depth[:block], poses[:block], intr, feats, block)  # warm-up
    cpu: list[float] = []
    acc, secs = fuse_vectorized(lat, depth, poses, intr, feats, block, cpu)
    fps = n_frames / secs
    t0, c0 = time.perf_counter(), time.process_time()
    acc.result()  # the fused cells, once per map: counted in the "with result" per-point cost
    result_secs, result_cpu = time.perf_counter() - t0, time.process_time() - c0
    zipon_cpu_us = 1e6 * (cpu[0] + result_cpu) / (n_frames * h * w)  # CPU time, all threads, result() included
    _, vsecs = fuse_voxels(lat, depth, poses, intr, feats, block, None)
    vfps = n_frames / vsecs
    loop, nsecs, npts, nframes, ncpu = time_loop(lat, depth, poses, intr, rgb, intr_img, feats.numpy(),
                                                 depth_min_m=0.1, depth_max_m=5.0, min_points=naive_points)
    naive_fps = nframes / nsecs
    naive_cpu_per_frame = ncpu / nframes
    real = {}
    if vlmaps_src is not None:
        from benchmarks.vlmaps_real import run_real_loop

        # VLMaps projects depth and colour with one matrix: colour at the depth's size; features (B,D,h,w)
        rgb_small = np.ascontiguousarray(rgb[:, rows[:, None], cols[None, :]])
        feats_bdhw = np.ascontiguousarray(feats.numpy().transpose(0, 3, 1, 2))
        runs, loop_cpu_us = [], [ncpu / npts * 1e6]
        for rep in range(2):  # alternating with our loop; CPU time: robust to other load on a shared machine
            runs.append(run_real_loop(vlmaps_src, depth[:nframes], poses[:nframes], intr, rgb_small, feats_bdhw,
                                      camera_height_m=CAMERA_HEIGHT_M, pitch=CAMERA_PITCH, sample_rate=1))
            if rep == 0:
                *_, p2, _, c2 = time_loop(lat, depth, poses, intr, rgb, intr_img, feats.numpy(), depth_min_m=0.1,
                                          depth_max_m=5.0, min_points=naive_points)
                loop_cpu_us.append(c2 / p2 * 1e6)
        best = min(runs, key=lambda r: r.cpu_us_per_point)
        real = dict(vlmaps_real_points=best.points, vlmaps_real_in_range=round(best.in_range / best.points, 3),
                    vlmaps_real_cpu_us_per_point=round(best.cpu_us_per_point, 2),
                    vlmaps_real_cpu_us_per_point_runs=[round(r.cpu_us_per_point, 2) for r in runs],
                    vlmaps_real_wall_us_per_point_runs=[round(r.us_per_point, 2) for r in runs],
                    vlmaps_loop_cpu_us_per_point_runs=[round(u, 2) for u in loop_cpu_us],
                    vlmaps_loop_over_real=round(min(loop_cpu_us) / best.cpu_us_per_point, 2),
                    zipon_cpu_us_per_point_with_result=round(zipon_cpu_us, 4),
                    cpu_speedup_vs_vlmaps_real=round(best.cpu_us_per_point / zipon_cpu_us, 1))
    lean_secs, lean_pts = fuse_lean(lat, depth, poses, intr, feats, 40_000)
    # correctness: our voxel accumulator with VLMaps' weights on exactly the frames the loop fused
    ref, _ = fuse_voxels(lat, depth[:nframes], poses[:nframes], intr, feats, len(feats), float(np.sqrt(SIGMA_SQ)))
    got = ref.result()
    cell, level, want = loop.voxels()
    same = np.array_equal(got.cell, cell) and np.array_equal(got.level, level)
    fields = dict(
         bench="fusion", size=f"{h}x{w}x{d}", frames=n_frames, block_frames=block, threads=torch.get_num_threads(),
         vectorized_frames_per_s=round(fps, 2), vectorized_ms_per_frame=round(1e3 / fps, 2),
         vectorized_us_per_point=round(1e6 / (fps * h * w), 4),
         vectorized_with_result_us_per_point=round(1e6 * (secs + result_secs) / (n_frames * h * w), 4),
         vectorized_cpu_us_per_point_with_result=round(zipon_cpu_us, 4),
         voxel_frames_per_s=round(vfps, 2),
         vlmaps_loop_frames=nframes, vlmaps_loop_points=npts, vlmaps_loop_us_per_point=round(nsecs / npts * 1e6, 2),
         vlmaps_loop_frames_per_s=round(naive_fps, 4), speedup_vs_vlmaps_loop=round(fps / naive_fps, 1),
         voxel_speedup_vs_vlmaps_loop=round(vfps / naive_fps, 1),
         vectorized_cpu_ms_per_frame=round(1e3 * cpu[0] / n_frames, 2),
         vlmaps_loop_cpu_ms_per_frame=round(1e3 * naive_cpu_per_frame, 1),
         cpu_time_speedup_vs_vlmaps_loop=round(naive_cpu_per_frame / (cpu[0] / n_frames), 1),
         lean_loop_us_per_point=round(lean_secs / lean_pts * 1e6, 2),
         speedup_vs_lean_loop=round(fps / (1.0 / (lean_secs / lean_pts * h * w)), 1),
         voxels_equal=bool(same), voxels=int(len(cell)),
         max_abs_diff=float(np.abs(got.features().numpy() - want).max()) if same else None,
         **real, features="synthetic unit vectors (encoder excluded)")
    emit(**fields)
    return fields


def bench_default_sampling(vlmaps_src: Path, zipon_fusion: dict, n_frames: int = 4) -> None:
    """Per FRAME at each method's default sampling, 640x480 frames: VLMaps' real loop over every 100th valid depth
    pixel (its ``depth_sample_rate``) vs zipon's vectorized fusion of every 120x160 feature cell (``zipon_fusion``,
    the 120x160x512 :func:`bench_fusion` result of this run)."""
    from benchmarks.vlmaps_real import VLMAPS_SAMPLE_RATE, run_real_loop

    depth, poses, intr = scene_frames(n_frames, 640, 480)
    feats = np.ascontiguousarray(synthetic_features(n_frames, 120, 160, 512).numpy().transpose(0, 3, 1, 2))
    rgb = np.random.default_rng(0).integers(0, 256, (n_frames, 480, 640, 3), dtype=np.uint8)
    r = run_real_loop(vlmaps_src, depth, poses, intr, rgb, feats, camera_height_m=CAMERA_HEIGHT_M,
                      pitch=CAMERA_PITCH, sample_rate=VLMAPS_SAMPLE_RATE)
    zipon_points = 120 * 160
    zipon_us = zipon_fusion["vectorized_cpu_us_per_point_with_result"]
    zipon_ms = zipon_us * zipon_points * 1e-3
    emit(bench="fusion_default_sampling", frames=n_frames, image="480x640", threads=torch.get_num_threads(),
         vlmaps_points_per_frame=round(r.points / r.frames), vlmaps_depth_sample_rate=VLMAPS_SAMPLE_RATE,
         vlmaps_cpu_us_per_point=round(r.cpu_us_per_point, 2),
         vlmaps_loop_cpu_ms_per_frame=round(r.loop_cpu_ms_per_frame, 2),
         vlmaps_call_wall_ms_per_frame=round(r.call_seconds / r.frames * 1e3, 1),
         zipon_points_per_frame=zipon_points, zipon_cpu_us_per_point=zipon_us, zipon_cpu_ms_per_frame=round(zipon_ms, 2),
         per_frame_ratio_vlmaps_over_zipon=round(r.loop_cpu_ms_per_frame / zipon_ms, 2),
         note="CPU time; vlmaps_call_wall_ms_per_frame adds its file reads, back-projection and map save (encoder "
              "stubbed)")


def bench_query(observed_fraction: float, repeats: int):
    from pipeline.config import QueryParams
    from pipeline.encoders.oracle import OracleEncoder
    from pipeline.maps.query import MapQuery
    from pipeline.maps.store import MapCells, SemanticMap
    from pipeline.maps.writer import write_map
    from pipeline.store import artifact_attrs

    lat = lattice()
    grid = lat.grid
    enc = OracleEncoder(dim=512)
    rng = np.random.default_rng(0)
    n_all = grid.rows * grid.cols
    cell = np.sort(rng.choice(n_all, int(n_all * observed_fraction), replace=False))
    # 48 object classes + background, cells in 12x12-cell patches of one class, each cell = class vector +
    # isotropic noise of norm ~0.3 (a clustered feature field; pure noise is no map)
    words = ["chair", "table", "sofa", "bed"] + [f"class{i}" for i in range(44)] + ["background"]
    table = np.stack([enc.word_vector(w) for w in words]).astype(np.float32)
    r, c = np.divmod(cell, grid.cols)
    patch = (r // 12) * 1000 + c // 12
    lab = np.where(rng.random(100_000) < 0.6, len(words) - 1, rng.integers(0, len(words) - 1, 100_000))[
        np.unique(patch, return_inverse=True)[1] % 100_000]
    feats = table[lab] + (0.3 / np.sqrt(512)) * rng.standard_normal((len(cell), 512)).astype(np.float32)
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    fused = MapCells(cell=cell, features=feats, weight=np.ones(len(cell), np.float32),
                     count=np.ones(len(cell), np.int32), level=np.zeros(len(cell), np.int16))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "vlmap.zarr"
        write_map(path, artifact_attrs("vlmap", 1, "vlmap", "bench", encoder=enc.identity()), grid, lat, fused,
                  tile_cells=64)
        for mode, rank in (("low-rank 64 + exact rescoring", 64), ("exact", 0)):
            t0 = time.perf_counter()
            mq = MapQuery(SemanticMap(path), enc, QueryParams(query_rank=rank))
            mq.query("chair", (3.0, 1.5, 0.0))  # warm: text cache, basis
            t_open = time.perf_counter() - t0
            times = []
            for i in range(repeats):
                t0 = time.perf_counter()
                r = mq.query(["chair", "table", "sofa", "bed"][i % 4], (3.0 + 0.01 * i, 1.5, 0.0))
                times.append(time.perf_counter() - t0)
            emit(bench="query", mode=mode, map=f"{grid.rows}x{grid.cols}x512", observed_cells=len(cell),
                 threads=torch.get_num_threads(), median_ms=round(1e3 * float(np.median(times)), 2),
                 p90_ms=round(1e3 * float(np.percentile(times, 90)), 2), open_and_first_query_s=round(t_open, 3),
                 winning_cells=int(r.wins.sum()), candidates=len(r.candidates), goal_ms=20)


def bench_scores(repeats: int):
    from pipeline.maps.scoring import chunked_scores

    n, d = 600 * 600, 512
    rng = np.random.default_rng(0)
    f32 = rng.standard_normal((n, d), dtype=np.float32)
    f32 /= np.linalg.norm(f32, axis=1, keepdims=True)
    f16 = f32.astype(np.float16)
    for t in (1, 5):
        text = rng.standard_normal((t, d), dtype=np.float32)
        text /= np.linalg.norm(text, axis=1, keepdims=True)
        out = {}
        for name, fn in (("fp32", lambda: f32 @ text.T), ("fp16", lambda: chunked_scores(f16, text))):
            fn()
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                fn()
                times.append(time.perf_counter() - t0)
            out[name] = 1e3 * float(np.median(times))
        err = float(np.abs(chunked_scores(f16, text) - f16.astype(np.float32) @ text.T).max())
        emit(bench="scores", map="600x600x512", prompts=t, threads=torch.get_num_threads(),
             fp32_median_ms=round(out["fp32"], 2), fp16_median_ms=round(out["fp16"], 2),
             fp32_features_mb=round(f32.nbytes / 2**20, 1), fp16_features_mb=round(f16.nbytes / 2**20, 1),
             max_abs_err=err)


def memory_child(n_frames: int) -> None:
    """Fuse ``n_frames`` (140 distinct ray-cast frames, cycled) at 120x160x512; print peak RSS."""
    depth, poses, intr = scene_frames(140, 160, 120)
    d120 = np.ascontiguousarray(depth[:, :, :])
    intr = intr
    feats = synthetic_features(16, 120, 160, 512)
    lat = lattice()
    acc = TopDownAccumulator(lat, 512)
    valid = np.ones((16, 120, 160), bool)
    before = peak_rss_mb()  # inputs + synthetic features in memory
    for s in range(0, n_frames, 16):
        idx = np.arange(s, min(s + 16, n_frames)) % 140
        pts = locate_block(lat, d120[idx], valid[: len(idx)], poses[idx], intr, depth_min_m=0.1, depth_max_m=5.0)
        acc.add(pts, feats[: len(idx)])
    res = acc.result()
    peak = peak_rss_mb()
    print(json.dumps({"frames": n_frames, "cells": len(res.cell), "peak_rss_mb": round(peak, 1),
                      "fusion_rss_growth_mb": round(peak - before, 1)}))


def bench_memory():
    out = {}
    for n in (140, 1400):
        r = subprocess.run([sys.executable, __file__, "--memory-child", str(n), "--threads", str(torch.get_num_threads())],
                           capture_output=True, text=True, check=True)
        out[n] = json.loads(r.stdout.strip().splitlines()[-1])
    emit(bench="memory", size="120x160x512", rss_mb_140=out[140]["peak_rss_mb"], rss_mb_1400=out[1400]["peak_rss_mb"],
         fusion_growth_mb_140=out[140]["fusion_rss_growth_mb"], fusion_growth_mb_1400=out[1400]["fusion_rss_growth_mb"],
         cells_140=out[140]["cells"], cells_1400=out[1400]["cells"],
         growth=round(out[1400]["peak_rss_mb"] / out[140]["peak_rss_mb"], 3))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="fewer frames and repeats")
    ap.add_argument("--memory-child", type=int, default=None)
    ap.add_argument("--only", choices=["fusion", "query", "scores", "memory"], default=None)
    ap.add_argument("--vlmaps-src", type=Path, default=None,
                    help="a checkout of github.com/vlmaps/vlmaps: also time its real loop (benchmarks/vlmaps_real.py)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    if a.memory_child is not None:
        memory_child(a.memory_child)
        return
    if a.only in (None, "fusion"):
        small = bench_fusion(120, 160, 512, 32 if a.quick else 96, naive_points=2 * 120 * 160, block=16,
                             vlmaps_src=a.vlmaps_src)
        if a.vlmaps_src is not None:
            bench_default_sampling(a.vlmaps_src, small)
        bench_fusion(480, 640, 512, 2 if a.quick else 4, naive_points=1, block=1)
    if a.only in (None, "query"):
        for frac in (1.0, 0.4):
            bench_query(frac, 5 if a.quick else 20)
    if a.only in (None, "scores"):
        bench_scores(5 if a.quick else 20)
    if a.only in (None, "memory"):
        bench_memory()


if __name__ == "__main__":
    main()
