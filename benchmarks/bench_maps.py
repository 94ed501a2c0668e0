"""Semantic map benchmarks: fusion throughput vs a naive per-point loop, query latency, peak memory.

Prints one JSON object per line. Fusion is timed with SYNTHETIC unit features of the stated size
(random, fixed seed) on ray-cast depth of the box-room fixture, so the encoder's cost is excluded;
the time covers back-projection, cell/level assignment and the scatter into the accumulator.

- ``fusion``: frames/s of :class:`TopDownAccumulator` at 120x160x512 and 480x640x512, and of a naive
  per-point Python loop (our own reference of VLMaps' loop, with the same top-level rule) on the
  same frames; the naive loop is timed on a sample of points and its frames/s extrapolated from
  the per-point cost. Both results are compared on the sampled frames (max abs difference).
- ``query``: latency of :meth:`MapQuery.query` (median of repeats, warm caches) on a 600x600 map
  with D=512, fully observed and 40% observed, 4 background prompts.
- ``memory``: peak RSS of a child process fusing 140 vs 1,400 frames (the 140 frames cycled), and its
  growth during fusion (after the inputs and the 16-frame block of synthetic features exist).

Run: ``.venv/bin/python benchmarks/bench_maps.py [--quick]``; threads: ``--threads 2``.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pipeline.geometry import GridSpec, Intrinsics  # noqa: E402
from pipeline.maps.fusion import Lattice, TopDownAccumulator, locate_block  # noqa: E402


def emit(**kw):
    print(json.dumps(kw), flush=True)


def scene_frames(n: int, width: int, height: int):
    from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames

    gt = box_room_gt()
    intr = Intrinsics.from_hfov(width, height, 90.0)
    poses = box_room_poses(n)
    _, depth_mm, _ = render_frames(gt, poses, intr)
    return depth_mm.astype(np.float32) * 1e-3, poses, intr


def lattice() -> Lattice:
    grid = GridSpec.centered((3.0, 1.5), 600, 600, 0.05)
    return Lattice(grid, 0.0, -0.05, 2.0, 0.1)


def synthetic_features(b: int, h: int, w: int, d: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    f = torch.randn((b, h, w, d), generator=g)
    return torch.nn.functional.normalize(f, dim=-1)


def fuse_vectorized(lat, depth, poses, intr, feats, block: int) -> tuple[TopDownAccumulator, float]:
    acc = TopDownAccumulator(lat, feats.shape[-1])
    valid = np.ones(depth.shape, bool)
    t0 = time.perf_counter()
    for s in range(0, len(depth), block):
        e = min(s + block, len(depth))
        pts = locate_block(lat, depth[s:e], valid[s:e], poses[s:e], intr, depth_min_m=0.1, depth_max_m=5.0)
        acc.add(pts, feats[: e - s])
    return acc, time.perf_counter() - t0


def fuse_naive(lat, depth, poses, intr, feats, max_points: int) -> tuple[dict, float, int]:
    """Per-point Python loop (VLMaps-style): project, bin, running weighted sum per cell with the top rule."""
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
                    return cells, time.perf_counter() - t0, n
                n += 1
                z = float(depth[b, v, u])
                if not (0.1 <= z <= 5.0):
                    continue
                p_cam = np.array([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z])
                p = R @ p_cam + t
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
    return cells, time.perf_counter() - t0, n


def bench_fusion(h: int, w: int, d: int, n_frames: int, naive_points: int, block: int):
    depth_img, poses, intr_img = scene_frames(n_frames, 2 * w if w < 640 else w, 2 * h if h < 480 else h)
    # features at (h, w): depth resampled the way DenseFeatures.resample_depth does (nearest at cell centres)
    H, W = depth_img.shape[1:]
    rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
    cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
    depth = np.ascontiguousarray(depth_img[:, rows[:, None], cols[None, :]])
    intr = intr_img.scaled(w, h)
    feats = synthetic_features(min(block, n_frames), h, w, d)
    lat = lattice()
    fuse_vectorized(lat, depth[:block], poses[:block], intr, feats, block)  # warm-up
    acc, secs = fuse_vectorized(lat, depth, poses, intr, feats, block)
    fps = n_frames / secs
    cells, nsecs, npts = fuse_naive(lat, depth, poses, intr, feats, naive_points)
    per_point = nsecs / max(npts, 1)
    naive_fps = 1.0 / (per_point * h * w)
    # correctness: the vectorized result on exactly the points the naive loop saw
    full_frames, rest = divmod(npts, h * w)
    check = {}
    if full_frames >= 1:
        ref = TopDownAccumulator(lat, d)
        fuse_vectorized_into(ref, lat, depth[:full_frames], poses[:full_frames], intr, feats)
        got = ref.result()
        keys = sorted(cells)
        if full_frames == npts // (h * w) and rest == 0:
            want = np.stack([cells[k][1] / np.linalg.norm(cells[k][1]) for k in keys])
            same = got.cell.tolist() == keys
            check = {"cells_equal": same,
                     "max_abs_diff": float(np.abs(got.features.numpy() - want).max()) if same else None}
    emit(bench="fusion", size=f"{h}x{w}x{d}", frames=n_frames, block_frames=block, threads=torch.get_num_threads(),
         vectorized_frames_per_s=round(fps, 2), vectorized_ms_per_frame=round(1e3 / fps, 2),
         naive_points_timed=npts, naive_us_per_point=round(per_point * 1e6, 2),
         naive_frames_per_s=round(naive_fps, 4), speedup=round(fps / naive_fps, 1),
         features="synthetic unit vectors (encoder excluded)", **check)


def fuse_vectorized_into(acc, lat, depth, poses, intr, feats):
    valid = np.ones(depth.shape, bool)
    for b in range(len(depth)):
        pts = locate_block(lat, depth[b : b + 1], valid[b : b + 1], poses[b : b + 1], intr, depth_min_m=0.1,
                           depth_max_m=5.0)
        acc.add(pts, feats[b % len(feats)][None])


def bench_query(observed_fraction: float, repeats: int):
    from pipeline.config import MapsParams
    from pipeline.encoders.oracle import OracleEncoder
    from pipeline.maps.fusion import FusedCells
    from pipeline.maps.query import MapQuery
    from pipeline.maps.store import SemanticMap, write_map
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
    fused = FusedCells(cell=cell, features=torch.from_numpy(feats), weight=np.ones(len(cell), np.float32),
                       count=np.ones(len(cell), np.int32), level=np.zeros(len(cell), np.int16))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "vlmap.zarr"
        write_map(path, artifact_attrs("vlmap", 1, "vlmap", "bench", encoder=enc.identity()), grid, lat, fused,
                  tile_cells=64)
        for mode, rank in (("low-rank 64 + exact rescoring", 64), ("exact", 0)):
            t0 = time.perf_counter()
            mq = MapQuery(SemanticMap(path), enc, MapsParams(query_rank=rank))
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


def memory_child(n_frames: int) -> None:
    """Fuse ``n_frames`` (140 distinct ray-cast frames, cycled) at 120x160x512; print peak RSS."""
    depth, poses, intr = scene_frames(140, 160, 120)
    d120 = np.ascontiguousarray(depth[:, :, :])
    intr = intr
    feats = synthetic_features(16, 120, 160, 512)
    lat = lattice()
    acc = TopDownAccumulator(lat, 512)
    valid = np.ones((16, 120, 160), bool)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # inputs + synthetic features in memory
    for s in range(0, n_frames, 16):
        idx = np.arange(s, min(s + 16, n_frames)) % 140
        pts = locate_block(lat, d120[idx], valid[: len(idx)], poses[idx], intr, depth_min_m=0.1, depth_max_m=5.0)
        acc.add(pts, feats[: len(idx)])
    res = acc.result()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
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
    ap.add_argument("--only", choices=["fusion", "query", "memory"], default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    if a.memory_child is not None:
        memory_child(a.memory_child)
        return
    if a.only in (None, "fusion"):
        bench_fusion(120, 160, 512, 32 if a.quick else 96, naive_points=2 * 120 * 160, block=16)
        bench_fusion(480, 640, 512, 2 if a.quick else 4, naive_points=20_000, block=1)
    if a.only in (None, "query"):
        for frac in (1.0, 0.4):
            bench_query(frac, 5 if a.quick else 20)
    if a.only in (None, "memory"):
        bench_memory()


if __name__ == "__main__":
    main()
