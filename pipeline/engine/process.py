"""Process tuning of a worker (or of the one process of a sync run): native thread counts, glibc's malloc
thresholds under a dask nanny, and the peak resident memory the manifests record. The runner, the evaluator
and the benchmarks call these; nothing here changes a result, only its speed and its memory figures."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def peak_rss_mb() -> float:
    """Peak resident memory of this (worker) process so far, MiB: ``VmHWM`` (per address space, so a worker forked
    from a big parent does not report the parent's ``ru_maxrss``), else ``ru_maxrss`` where ``/proc`` is missing."""
    import resource

    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
    return peak / (1 << 20 if platform.system() == "Darwin" else 1 << 10)


def restore_malloc_defaults() -> None:
    """Give this process glibc's own malloc thresholds back when a dask nanny set ``MALLOC_TRIM_THRESHOLD_``.

    distributed's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536`` (config
    ``distributed.nanny.pre-spawn-environ``) so that freed memory returns to the OS. Setting any trim threshold
    also turns off glibc's dynamic mmap threshold, so every buffer over 128 KiB (a 640x480 frame, a block of
    features) is mmapped and page-faulted afresh each time: a 1,416-frame scene's ingest took 82 CPU s in a worker
    (38 of them in the kernel) against 36 with glibc's defaults. Here the thresholds are set to where glibc's
    dynamic rule ends up (mmap above 32 MiB, trim above 64 MiB), on any worker: ours (``processes``) or a user's
    ``dask worker`` (``tcp://``). Memory stays bounded by the stages' blocks, not by these thresholds. Linux/glibc
    only; elsewhere, or without that variable, nothing is changed."""
    global _MALLOC_RESTORED
    if _MALLOC_RESTORED or "MALLOC_TRIM_THRESHOLD_" not in os.environ or platform.system() != "Linux":
        return
    _MALLOC_RESTORED = True
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # not glibc (musl, ...): its malloc does not read that variable either
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    libc.mallopt(m_mmap_threshold, 32 << 20)
    libc.mallopt(m_trim_threshold, 64 << 20)


_MALLOC_RESTORED = False


def release_free_memory() -> None:
    """Hand the heap pages freed since the last call back to the OS: a garbage collection, then glibc's
    ``malloc_trim(0)``, which releases the free pages inside every arena, not only above each arena's top.

    A worker process runs stage after stage, and their threads (readers, writers, prefetchers, dask's) each
    allocate in their own arena; blocks freed in the middle of an arena stay resident otherwise, so a worker's
    memory ratcheted up from scene to scene to more than any one stage needs. The runner calls this after each
    stage and each map chunk. Linux/glibc only; elsewhere only the collection runs."""
    import gc

    gc.collect()
    if platform.system() != "Linux":
        return
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc (musl, ...)
        pass


def limit_native_threads(n: int) -> None:
    """Cap BLAS/OpenMP/torch/open3d threads inside a worker (dask runs one task per worker thread), and restore
    glibc's malloc thresholds there (:func:`restore_malloc_defaults`).

    Speed only: outputs do not depend on thread counts (open3d's parallel reductions are made canonical or
    run single-threaded where they would; see pipeline.recon)."""
    global _NATIVE_THREADS
    restore_malloc_defaults()
    _NATIVE_THREADS = n
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(n)
    try:
        import torch

        torch.set_num_threads(n)
    except ImportError:
        pass
    try:
        import open3d as o3d  # 0.20 runs its kernels on TBB threads, which OMP_NUM_THREADS does not cap

        o3d.utility.set_max_threads(n)
    except (ImportError, AttributeError):
        pass


_NATIVE_THREADS: int | None = None


def native_threads() -> int | None:
    """The thread count :func:`limit_native_threads` last set in this process (None: never set)."""
    return _NATIVE_THREADS


def process_counters() -> dict[str, int]:
    """This process's counters since it started: page faults served from memory (``minor_faults``) and from disk
    (``major_faults``), context switches it asked for (``waits``: I/O, locks) and was forced into
    (``preempted``: another runnable process took the core), bytes its reads asked for (``read_bytes``: page cache
    included, so a frame read twice counts twice) and bytes read from the disk itself (``disk_read_bytes``; absent
    where ``/proc/self/io`` is not readable). :func:`counters_since` turns two readings into what a stage did."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF)
    out = {"minor_faults": ru.ru_minflt, "major_faults": ru.ru_majflt, "waits": ru.ru_nvcsw,
           "preempted": ru.ru_nivcsw}
    try:
        io = dict(line.split(": ") for line in Path("/proc/self/io").read_text().splitlines())
        out.update(read_bytes=int(io["rchar"]), disk_read_bytes=int(io["read_bytes"]))
    except (OSError, KeyError, ValueError):
        pass
    return out


def counters_since(before: dict[str, int]) -> dict[str, int]:
    """:func:`process_counters` now minus ``before`` (the counters both readings have)."""
    now = process_counters()
    return {k: now[k] - before[k] for k in now if k in before}
