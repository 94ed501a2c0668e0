"""Does a core's work cost more CPU time when the other core is busy? Each kernel runs alone, then as two copies at
once in two processes; per copy it prints CPU seconds and the ratio two-at-once / alone (1.0: the cores do not
slow each other; well above 1: they share something, e.g. SMT siblings on the host, memory bandwidth or the last
level cache). This separates what ``zipon run``'s code can fix (its own overhead in a batch) from what the machine
imposes on any two processes.

Kernels, each fixed work: ``alu`` (a pure-Python integer loop: almost no memory traffic), ``stream`` (numpy copies
of 256 MiB arrays: memory bandwidth), ``zstd`` (zstd level 1 of a 640x480 colour-like frame, the compressor inside frames.zarr's
blosc codec), and ``integrate`` (open3d's TSDF integrate, one thread, on ``--frames`` of a frames.zarr given with
``--frames-zarr``; skipped without it). One JSON object per line on stdout.

    .venv/bin/python benchmarks/bench_contention.py [--frames-zarr data/artifacts/sim_00/frames.zarr]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time
from pathlib import Path

from _common import emit


def _alu(scale: int) -> None:
    x = 0
    for i in range(6_000_000 * scale):
        x = (x + i * 7) % 1_000_003


def _stream(scale: int) -> None:
    import numpy as np

    a = np.ones(32 << 20)  # 256 MiB of float64
    b = np.empty_like(a)
    for _ in range(12 * scale):
        np.copyto(b, a)
        np.copyto(a, b)


def _zstd(scale: int) -> None:
    import numpy as np
    import zstandard

    rng = np.random.default_rng(0)
    frame = (np.cumsum(rng.integers(-3, 4, size=(480, 640, 3)), axis=1) % 256).astype(np.uint8).tobytes()
    codec = zstandard.ZstdCompressor(level=1)
    for _ in range(200 * scale):
        codec.compress(frame)


def _integrate(scale: int, frames_zarr: str, frames: int) -> None:
    import open3d as o3d

    from pipeline.frames import FrameStore
    from pipeline.config import ReconstructParams
    from pipeline.recon.tsdf import integrate, new_volume, prepare_block, strided, with_stride

    o3d.utility.set_max_threads(1)
    p = ReconstructParams()
    store = FrameStore(Path(frames_zarr))
    n = min(frames, store.n_frames)
    p = with_stride(p, store.intrinsics)
    block = prepare_block(store.read(0, n), p)
    intr = strided(store.intrinsics, p.depth_stride)
    for _ in range(scale):
        volume = new_volume(p)
        for j in range(n):
            if block.has_depth[j]:
                integrate(volume, block.depth_mm[j], block.rgb[j], block.T_world_camera[j], intr, p)


def _timed(job: tuple, barrier, results) -> None:
    """Run one kernel in this process: its setup, then wait for every copy to be ready, then the timed work."""
    name, extra = job[0], job[1:]
    fn = {"alu": _alu, "stream": _stream, "zstd": _zstd, "integrate": _integrate}[name]
    if name == "integrate":
        fn(0, *extra[1:])  # imports and the frames read before timing: integrate's setup is heavy
    barrier.wait()  # the copies start their timed work together, so they overlap
    c0, t0 = time.process_time(), time.perf_counter()
    fn(*extra)
    results.put((time.process_time() - c0, time.perf_counter() - t0))


def _copies(ctx, job: tuple, n: int) -> list[tuple[float, float]]:
    """(CPU s, wall s) of each of ``n`` copies of ``job`` run at once, one process each."""
    barrier, results = ctx.Barrier(n), ctx.Queue()
    procs = [ctx.Process(target=_timed, args=(job, barrier, results)) for _ in range(n)]
    for proc in procs:
        proc.start()
    out = [results.get() for _ in procs]
    for proc in procs:
        proc.join()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames-zarr", default=None, help="a frames.zarr for the integrate kernel")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--kernels", nargs="+", default=["alu", "stream", "zstd", "integrate"])
    ap.add_argument("--scale", type=int, default=4, help="work of the alu, stream and zstd kernels (x ~1-2 s)")
    args = ap.parse_args()
    ctx = mp.get_context("spawn")
    for name in args.kernels:
        if name == "integrate" and not args.frames_zarr:
            continue
        job = (name, 1, args.frames_zarr, args.frames) if name == "integrate" else (name, args.scale)
        alone = _copies(ctx, job, 1)[0]
        both = _copies(ctx, job, 2)
        emit(bench="contention", kernel=name, alone_cpu_s=round(alone[0], 3), alone_wall_s=round(alone[1], 3),
             two_at_once_cpu_s=[round(b[0], 3) for b in both], two_at_once_wall_s=[round(b[1], 3) for b in both],
             cpu_ratio=round(sum(b[0] for b in both) / 2 / alone[0], 3))


if __name__ == "__main__":
    main()
