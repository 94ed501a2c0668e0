"""Whole-batch benchmark: N simulated scenes x F frames through ``zipon run`` with 1 and 2 workers.

The logs are written first (``zipon run --stage simulate``, NOT timed); then, for each worker count,
``zipon run --force`` runs ingest -> reconstruct -> vlmap + cfmap (oracle encoder) -> goals -> routes
with the ``processes`` scheduler in a fresh process. Per stage it prints, from the stage manifests
(``timing``: wall seconds, CPU seconds, peak RSS of the worker process), frames/s per worker, CPU
seconds, wall seconds, peak RSS, the worker's page faults, preemptions and MB read per frame (``timing.counters``:
where extra CPU in a big batch goes), and the ratio of the stage's seconds per frame to a BARE kernel measured
in the same run, single-threaded, on the same data:

- ``ingest``: the honest floor of ingest (:func:`kernel_ingest_floor`): reading the logs' messages with CRC checks
  (chunk zstd decode included), parsing each image payload into its array, encoding and writing the arrays to a
  zarr store on disk with frames.zarr's codecs, and their BLAKE3 digests, each part printed (``ingest_floor``
  line; the zstd decode alone is printed beside it);
- ``reconstruct``: open3d's ``VoxelBlockGrid`` ``compute_unique_block_coordinates`` + ``integrate``
  alone on frames already decoded and prepared (:mod:`pipeline.recon.tsdf` with the run's params);
- ``vlmap`` / ``cfmap``: ``torch.index_add_`` of ``h*w`` x ``D`` fp32 feature rows per frame (the
  encoder's output size) into an accumulator: the scatter every dense fusion has to do.

It also runs each map stage's unit of work once more in-process on the first scene and prints the
encoder's share of its CPU time (``encoder_share``; target: the oracle at most 5 %).

A stage's CPU seconds are its worker process's over the stage's span: while a map stage waits for its chunks
or for its turn to fold them (seceded), its worker runs other tasks, whose CPU is then counted twice, so under
``processes`` the per-stage figures are upper bounds, and the map stages' are the in-process ``encoder_share``
lines' (one scene, nothing else running; their ``stage_cpu_ratio_to_kernel`` is that stage's CPU a frame over
the ``index_add`` kernel's). A stage's ``wall_s`` leaves out the time it stood in line for a turn
(``waited_s``, the manifests' ``timing.waited_seconds``). Each run's ``cpu_s`` is exact: ``getrusage`` of every
process of the run.

Each run's line also gives its wall time, frames/s over the whole batch, the largest worker's
peak RSS (the workers' ``ru_maxrss`` and zipon's own ``VmHWM``) and the wall time the same rate implies for the
paper's 14,159 frames (``--target-frames``), and the wall time its CPU seconds imply when the
workers each have a core of their own (``projected_wall_min_if_cpu_bound``: CPU seconds per frame
x target frames / workers; the figure for an otherwise idle machine, ignoring scene imbalance), and the wall time
the stages' bare kernels alone imply (``kernel_floor_wall_min_for_target``: the kernels' CPU seconds a frame,
summed over the stages run, x target frames / workers), below which no scheduling or overhead work can bring a
run: a target under it needs less work per frame. The machine's 1-minute load average is printed on
every line: on a shared machine wall times are upper bounds, CPU seconds are the steadier figure.
One JSON object per line on stdout.

    .venv/bin/python benchmarks/bench_batch.py                      # 10 scenes x 1,416 frames (slow)
    .venv/bin/python benchmarks/bench_batch.py --scenes 2 --frames 240 --workers 1 2
    .venv/bin/python benchmarks/bench_batch.py --scenes 1 --frames 1400 --workers 1 --keep /tmp/batch

A batch's CPU seconds per frame can only be compared with one scene's run alone on the same scene (the apartments
differ in size, and reconstruct's cost follows the surface each frame sees): ``--alone SCENE ...`` reruns those
scenes one at a time on 1 worker after the batch and prints, per stage, the scene's CPU seconds in the last batch
run over alone (``batch_vs_alone``).

``--within-scene`` measures one scene's map stages instead (:func:`within_scene`): the logs, ingest and
reconstruct are built first (not timed); then ``zipon run --force --stage vlmap`` (``--map-stages``) with 1 and
with 2 workers (``processes``: a local dask cluster; the chunks of ``maps.chunk_frames`` frames of the one scene
are spread over the workers), printing wall seconds, the CPU seconds of every process of the run (``getrusage``
of the finished children) and whether the maps' digests agree across worker counts; then the incremental rerun:
the map built in this process on the scene cut to its first ``frames - append`` frames (frames.zarr and
recon.zarr truncated: recon keeps its grid, the case where the fold is reusable), keeping its fold, and rebuilt
on all the frames, timed, with the check that it equals the map ``zipon run`` built from scratch.

    .venv/bin/python benchmarks/bench_batch.py --within-scene --frames 1400 --workers 1 2 --append 200

``--real-encoders`` measures one scene's map stage (default 16 frames at 640x480, LSeg on the first 4 of them;
built upstream first, not timed)
with each real encoder at its default size, from random weights saved to files (the same compute as trained ones;
nothing is downloaded): open_clip ViT-B/32 MaskCLIP at 480x640 and the public-size LSeg (ViT-L/16, 480 px windows)
for the vlmap, ConceptFusion for the cfmap with ``--encoders conceptfusion``. Per encoder it prints the stage's
CPU seconds split into the encoder's forward passes, its model loads (fixed per chunk) and the rest, the ratio
rest / encoder (target: at most 0.10, encoder-bound), frames/s and CPU seconds per frame, and the CPU
hours the paper's 14,159 frames would take (divide by the cores or GPUs a user has). ``--device cuda:0
--precision bf16`` runs the encoders on a GPU under autocast; each row then also gives the encoder's wall
seconds (the device synchronised after each forward pass), its frames/s, and the stage's wall share spent
outside the encoder (``benchmarks/bench_gpu.sh`` runs the three encoders that way).

    .venv/bin/python benchmarks/bench_batch.py --real-encoders --frames 16 --encoders maskclip lseg
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, emit

STAGES = ("ingest", "reconstruct", "vlmap", "cfmap", "goals", "routes")
KERNEL_OF = {"ingest": "ingest_floor", "reconstruct": "o3d_integrate", "vlmap": "index_add", "cfmap": "index_add"}


def write_params(root: Path, scenes: int, frames: int, width: int, height: int) -> Path:
    import yaml

    params = {
        "scenes": {f"sim_{i:02d}": {"format": "auto", "source": "simulate"} for i in range(scenes)},
        "simulate": {"frames": frames, "width": width, "height": height},
        "encoders": {"simulated": "oracle"},
        "run": {"scheduler": "processes", "threads_per_worker": 1},
    }
    path = root / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


#: zipon's own peak is its VmHWM, not its ru_maxrss: Linux carries the resident memory of the process that forked
#: it into an exec'd process's ru_maxrss (this benchmark held 3.4 GB of kernel timings when it started zipon, and
#: zipon's ru_maxrss said 3,398 MB while its VmHWM was under 0.2 GB). Its workers are spawned from zipon's small
#: main process, so their ru_maxrss (RUSAGE_CHILDREN) is their own.
ZIPON = ("import resource, sys; from zipon.cli import main; from pipeline.engine.process import peak_rss_mb; "
         "code = main(sys.argv[1:]); kid = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss; "
         "me = int(peak_rss_mb() * 1024); print('PEAK_RSS_KB', max(kid, me), file=sys.stderr); sys.exit(code)")


def zipon(params: Path, *args: str) -> tuple[float, float]:
    """Run ``zipon -p params -q ARGS`` in a fresh process; (wall seconds, largest process's peak RSS in MB)."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "DVC_NO_ANALYTICS": "1", "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", ZIPON, "-p", str(params), "-q", *args], cwd=params.parent,
                          env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"zipon {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    peak = [int(line.split()[1]) for line in proc.stderr.splitlines() if line.startswith("PEAK_RSS_KB")]
    return wall, (peak[-1] / 1024.0 if peak else float("nan"))


def manifests(root: Path, scenes: list[str], stages: list[str]) -> dict[str, list[dict]]:
    """stage -> the manifests' ``timing`` of every scene."""
    out: dict[str, list[dict]] = {s: [] for s in stages}
    for scene in scenes:
        for stage in stages:
            m = json.loads((root / "manifests" / scene / f"{stage}.json").read_text())
            out[stage].append(m["timing"])
    return out


# ----------------------------------------------------------------------------- bare kernels

def kernel_zstd(logs: list[Path]) -> tuple[float, float]:
    """(wall, CPU) seconds of zstd-decompressing every MCAP chunk of ``logs`` (chunk records read beforehand)."""
    import zstandard
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    chunks = []
    for log in logs:
        with open(log, "rb") as f:
            chunks += [(r.data, r.uncompressed_size) for r in StreamReader(f, emit_chunks=True).records
                       if isinstance(r, Chunk) and r.compression == "zstd"]
    if not chunks:
        raise SystemExit(f"{logs}: no zstd chunks (the simulator's logs are zstd-compressed MCAP)")
    dec = zstandard.ZstdDecompressor()
    t0, c0 = time.perf_counter(), time.process_time()
    for data, size in chunks:
        dec.decompress(data, max_output_size=size)
    return time.perf_counter() - t0, time.process_time() - c0


def kernel_ingest_floor(logs: list[Path], workdir: Path, level: int, block: int = 16) -> dict[str, float]:
    """Seconds of the work no ingest can skip, each part timed alone on every image of ``logs``: reading the MCAP
    messages with CRC checks (``mcap``'s reader: chunk zstd decode included), turning each ``sensor_msgs/Image``
    payload into its array (``pipeline.ros2.parse_image_cdr`` + ``np.frombuffer``), encoding and writing those
    arrays in blocks of ``block`` frames to a zarr v3 store on disk with frames.zarr's codecs (blosc-zstd at
    ``level``: no shuffle for uint8 images, byte shuffle for uint16), and their BLAKE3 digests. Only one block of
    frames is held at a time. Returns the wall seconds per part, ``cpu`` (the CPU seconds of all of it, every thread
    of this process) and ``images``."""
    import blake3
    import numpy as np
    import zarr
    from mcap.reader import make_reader

    from pipeline.ros2 import parse_image_cdr
    from pipeline.store import compressor

    spent = {"read": 0.0, "parse": 0.0, "encode": 0.0, "hash": 0.0}
    images, cpu0 = 0, time.process_time()
    for n_log, log in enumerate(logs):
        group = zarr.open_group(workdir / f"floor_{n_log}.zarr", mode="w")
        pending: dict[str, list] = {}
        arrays: dict[str, zarr.Array] = {}
        hashes: dict[str, blake3.blake3] = {}

        def flush(topic: str) -> None:
            rows = np.stack(pending.pop(topic))
            t0 = time.perf_counter()
            if topic not in arrays:
                shuffle = "noshuffle" if rows.dtype == np.uint8 else "shuffle"
                arrays[topic] = group.create_array(topic.strip("/").replace("/", "_"), shape=(0, *rows.shape[1:]),
                                                   chunks=(block, *rows.shape[1:]), dtype=rows.dtype,
                                                   compressors=compressor(level, shuffle=shuffle))
            z = arrays[topic]
            n = z.shape[0]
            z.resize((n + len(rows), *z.shape[1:]))
            z[n:] = rows
            t1 = time.perf_counter()
            hashes.setdefault(topic, blake3.blake3()).update(rows.reshape(-1).view(np.uint8))
            spent["encode"] += t1 - t0
            spent["hash"] += time.perf_counter() - t1

        with open(log, "rb") as f:
            messages = make_reader(f, validate_crcs=True).iter_messages()
            while True:
                t0 = time.perf_counter()
                item = next(messages, None)
                t1 = time.perf_counter()
                spent["read"] += t1 - t0
                if item is None:
                    break
                schema, channel, message = item
                if schema is None or schema.name not in ("sensor_msgs/msg/Image", "sensor_msgs/Image"):
                    continue
                msg = parse_image_cdr(message.data)
                dtype = np.uint16 if msg["encoding"] in ("16UC1", "mono16") else np.uint8
                rows = np.frombuffer(msg["data"], dtype=dtype).reshape(msg["height"], msg["width"], -1)
                rows = rows[..., 0] if rows.shape[-1] == 1 else rows
                spent["parse"] += time.perf_counter() - t1
                images += 1
                pending.setdefault(channel.topic, []).append(rows)
                if len(pending[channel.topic]) == block:
                    flush(channel.topic)
        for topic in list(pending):
            flush(topic)
        shutil.rmtree(workdir / f"floor_{n_log}.zarr")
    return {**spent, "cpu": time.process_time() - cpu0, "images": images}


def kernel_integrate(params_path: Path, frames_zarr: Path, n: int) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds, frames) of open3d's integrate alone (with its block allocation,
    ``compute_unique_block_coordinates``), on one thread as the stage runs it with ``run.threads_per_worker: 1``,
    over the first ``n`` frames (0: every frame, the frames the stage integrates: the cost per frame depends on
    how much of the scene each frame sees), read and prepared a block at a time outside the timing."""
    import open3d as o3d

    from pipeline.paramsfile import load_params
    from pipeline.frames import FrameStore
    from pipeline.recon.tsdf import integrate, new_volume, prepare_block, strided, with_stride

    p = load_params(params_path).reconstruct
    store = FrameStore(frames_zarr)
    n = store.n_frames if n <= 0 else min(n, store.n_frames)
    p = with_stride(p, store.intrinsics)
    intr = strided(store.intrinsics, p.depth_stride)
    volume = new_volume(p)
    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    wall = cpu = 0.0
    for raw in store.iter_blocks(p.block_frames, stop=n):
        block = prepare_block(raw, p)
        t0, c0 = time.perf_counter(), time.process_time()
        for j in range(len(block.depth_mm)):
            if block.has_depth[j]:
                integrate(volume, block.depth_mm[j], block.rgb[j], block.T_world_camera[j], intr, p)
        wall, cpu = wall + time.perf_counter() - t0, cpu + time.process_time() - c0
    o3d.utility.set_max_threads(before)
    return wall, cpu, n


def kernel_index_add(h: int, w: int, dim: int, frames: int = 16, cells: int = 40_000) -> tuple[float, float]:
    """(wall, CPU) seconds per frame of ``index_add_`` of ``h*w`` random-cell rows of ``dim`` fp32 into ``cells``
    rows."""
    import torch

    g = torch.Generator().manual_seed(0)
    feats = torch.nn.functional.normalize(torch.randn(h * w, dim, generator=g), dim=1)
    acc = torch.zeros(cells, dim)
    idx = [torch.randint(0, cells, (h * w,), generator=g) for _ in range(frames)]
    acc.index_add_(0, idx[0], feats)  # warm
    t0, c0 = time.perf_counter(), time.process_time()
    for i in idx:
        acc.index_add_(0, i, feats)
    return (time.perf_counter() - t0) / frames, (time.process_time() - c0) / frames


def encoder_share(params_path: Path, root: Path, scene: str, kind: str, params=None, frames: int | None = None) -> dict:
    """CPU seconds of one map stage's unit of work (``build_map``) on ``scene``, in this process, split into the
    encoder's forward passes (``Encoder.encode_images``, timed by a wrapper), its model loads (``build_encoder``:
    once for the map's identity, once per chunk task; a fixed cost per chunk, not per frame) and the rest (frames
    read, projection, fusion, the store written). ``params``: the Params to use instead of ``params_path``'s;
    ``frames``: map only the scene's first ``frames`` frames (copies of frames.zarr and recon.zarr cut short)."""
    import pipeline.encoders
    from pipeline.paramsfile import load_params
    from pipeline.encoders.base import Encoder
    from pipeline.maps import fusion, store  # noqa: F401  (imported before timing: not the stage's work)
    from pipeline.maps.build import build_map
    from pipeline.maps.config import MAP_CONFIGS
    from pipeline.recon import Recon  # noqa: F401
    from pipeline.scene_gt import GTScene  # noqa: F401
    from pipeline.store import artifact_attrs

    import torch

    spent = {"encode": 0.0, "load": 0.0, "encode_wall": 0.0}
    encode, build = Encoder.encode_images, pipeline.encoders.build_encoder
    gpu = torch.cuda.is_available()

    def clocked(fn, key):
        def wrapper(*a, **kw):
            t0, w0 = time.process_time(), time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                if gpu:  # kernels run asynchronously: the forward pass ends when the device is done
                    torch.cuda.synchronize()
                spent[key] += time.process_time() - t0
                if key == "encode":
                    spent["encode_wall"] += time.perf_counter() - w0
        return wrapper

    params = params or load_params(params_path)
    config = MAP_CONFIGS[kind].from_params(params, scene)
    art = root / "data" / "artifacts" / scene
    out = Path(tempfile.mkdtemp(prefix=f"share-{kind}-")) / f"{kind}.zarr"
    frames_zarr, recon_zarr = art / "frames.zarr", art / "recon.zarr"
    if frames:
        frames_zarr = _truncated(frames_zarr, out.parent / "frames.zarr", frames, FRAME_ARRAYS)
        recon_zarr = _truncated(recon_zarr, out.parent / "recon.zarr", frames, RECON_FRAME_ARRAYS)
    Encoder.encode_images = clocked(encode, "encode")
    pipeline.encoders.build_encoder = clocked(build, "load")
    try:
        t0, w0 = time.process_time(), time.perf_counter()
        summary = build_map(config, frames_zarr, recon_zarr, out, artifact_attrs(kind, 1, kind, "bench"),
                            runtime=params.run)
        stage, wall = time.process_time() - t0, time.perf_counter() - w0
    finally:
        Encoder.encode_images, pipeline.encoders.build_encoder = encode, build
        shutil.rmtree(out.parent, ignore_errors=True)
    rest = stage - spent["encode"] - spent["load"]
    return {"map": kind, "encoder": config.encoder, "chunks": summary["chunks"], "stage_wall_s": round(wall, 3),
            "stage_cpu_s": round(stage, 3), "encoder_cpu_s": round(spent["encode"], 3),
            "model_load_cpu_s": round(spent["load"], 3), "other_cpu_s": round(rest, 3),
            "encoder_share": round(spent["encode"] / stage, 4),
            "other_over_encoder": round(rest / spent["encode"], 4) if spent["encode"] else None,
            "encoder_wall_s": round(spent["encode_wall"], 3),
            "outside_encoder_wall_share": round(1 - spent["encode_wall"] / wall, 4) if wall else None,
            "device": params.run.device, "precision": params.run.precision}


def real_encoders(args) -> None:
    """One scene's map stage with each real encoder (random weights saved to files: the same compute as trained
    ones) at its default size: the encoder's share of the stage and frames/s per encoder (see the module docstring)."""
    import open_clip
    import torch

    from pipeline.paramsfile import load_params
    from pipeline.encoders.lseg_net import LSEG_VITL16_384, LSegNet

    root = args.keep or Path(tempfile.mkdtemp(prefix="zipon-encoders-"))
    root.mkdir(parents=True, exist_ok=True)
    params_path = write_params(root, 1, args.frames, args.width, args.height)
    scene = "sim_00"
    emit(bench="batch", kind="setup", mode="real_encoders", frames=args.frames, size=[args.width, args.height],
         encoders=args.encoders, cpus=os.cpu_count(), torch_threads=torch.get_num_threads(), root=str(root))
    try:
        t_up, _ = zipon(params_path, "run", "--stage", "simulate", "--stage", "ingest", "--stage", "reconstruct")
        emit(bench="batch", kind="upstream_built", seconds=round(t_up, 1), timed=False)
        torch.manual_seed(0)
        clip = root / "open_clip_vit_b32_random.pt"
        if not clip.exists():
            torch.save(open_clip.create_model("ViT-B-32", pretrained=None).state_dict(), clip)
        lseg = root / "lseg_vitl16_random.ckpt"
        if "lseg" in args.encoders and not lseg.exists():
            torch.save({"state_dict": {f"net.{k}": v for k, v in LSegNet(LSEG_VITL16_384).state_dict().items()}}, lseg)
        base = load_params(params_path)
        for name in args.encoders:
            kind = "cfmap" if name == "conceptfusion" else "vlmap"
            weights = getattr(base.encoders, name).model_copy(update={"weights": str(lseg if name == "lseg" else clip)})
            enc = base.encoders.model_copy(update={"simulated": None, kind: name, name: weights})
            run = base.run.model_copy(update={"device": args.device, "precision": args.precision})
            params = base.model_copy(update={"encoders": enc, "run": run})
            frames = min(args.lseg_frames, args.frames) if name == "lseg" else args.frames
            row = encoder_share(params_path, root, scene, kind, params=params,
                                frames=frames if frames < args.frames else None)
            emit(bench="batch", kind="real_encoder", frames=frames, **row,
                 frames_per_s=round(frames / row["stage_wall_s"], 3),
                 cpu_s_per_frame=round(row["stage_cpu_s"] / frames, 3),
                 encoder_cpu_s_per_frame=round(row["encoder_cpu_s"] / frames, 3),
                 encoder_frames_per_s=round(frames / row["encoder_wall_s"], 3) if row["encoder_wall_s"] else None,
                 target_other_over_encoder=0.10,
                 projected_cpu_hours_for_target=round(args.target_frames * row["stage_cpu_s"] / frames / 3600, 1),
                 target_frames=args.target_frames)
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


# ----------------------------------------------------------------------------- one scene's map stages

def _children_cpu_s() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


FRAME_ARRAYS = ("rgb", "depth", "instance", "pose", "stamp")  # frames.zarr's per-frame arrays
RECON_FRAME_ARRAYS = ("pose", "fused")  # recon.zarr's


def _truncated(src: Path, dst: Path, n: int, arrays: tuple[str, ...]) -> Path:
    """A copy of the zarr store ``src`` at ``dst`` with ``arrays`` cut to their first ``n`` entries."""
    import zarr

    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst)
    group = zarr.open_group(dst, mode="r+")
    for name in arrays:
        if name in group:
            group[name].resize((n,) + group[name].shape[1:])
    if "n_frames" in group.attrs:
        group.attrs["n_frames"] = n
    return dst


def incremental_rerun(params_path: Path, root: Path, scene: str, stage: str, append: int) -> dict:
    """Build ``stage`` in this process on the scene cut to ``n - append`` frames keeping its fold, then on all ``n``
    frames (timed); the second map must equal the one ``zipon run`` built from scratch (its digest)."""
    from pipeline.engine.codedeps import code_digest
    from pipeline.paramsfile import load_params
    from pipeline.frames import FrameStore
    from pipeline.maps.build import build_map
    from pipeline.maps.config import MAP_CONFIGS
    from pipeline.maps.store import FORMAT_VERSION
    from pipeline.engine.process import limit_native_threads
    from pipeline.store import artifact_attrs, content_digest

    params = load_params(params_path)
    limit_native_threads(params.run.threads_per_worker)  # as in a worker
    art = root / "data" / "artifacts" / scene
    manifest = json.loads((root / "manifests" / scene / f"{stage}.json").read_text())
    work = Path(tempfile.mkdtemp(prefix=f"incremental-{stage}-", dir=root))
    try:
        n = FrameStore(art / "frames.zarr").n_frames
        before = n - append
        frames = _truncated(art / "frames.zarr", work / "frames.zarr", before, FRAME_ARRAYS)
        recon = _truncated(art / "recon.zarr", work / "recon.zarr", before, RECON_FRAME_ARRAYS)
        config = MAP_CONFIGS[stage].from_params(params, scene)
        attrs = artifact_attrs(stage, FORMAT_VERSION, stage, manifest["params_digest"])
        kw = {"runtime": params.run, "fold_path": work / "fold",
              "fold_key": {"params": manifest["params_digest"], "code": code_digest(f"stages.{stage}")}}
        t0, c0 = time.perf_counter(), time.process_time()
        first = build_map(config, frames, recon, work / "before.zarr", attrs, **kw)
        t1, c1 = time.perf_counter(), time.process_time()
        again = build_map(config, art / "frames.zarr", art / "recon.zarr", work / "after.zarr", attrs, **kw)
        t2, c2 = time.perf_counter(), time.process_time()
        fold_mb = sum(f.stat().st_size for f in (work / "fold").iterdir()) / 2**20
        return {"map": stage, "frames_before": before, "frames_after": n, "first_build_s": round(t1 - t0, 2),
                "first_build_cpu_s": round(c1 - c0, 2), "rerun_s": round(t2 - t1, 2), "rerun_cpu_s": round(c2 - c1, 2),
                "chunks_reused": again["chunks_reused"], "frames_reused": again["frames_reused"],
                "frames_processed": again["frames_processed"], "fold_cache_mb": round(fold_mb, 1),
                "chunks_before": first["chunks"],
                "equals_map_from_scratch": content_digest(work / "after.zarr") == manifest["outputs"][stage]["digest"]}
    finally:
        shutil.rmtree(work, ignore_errors=True)


def within_scene(args) -> None:
    """One scene's map stages with 1 and 2 workers, and the incremental rerun (see the module docstring)."""
    root = args.keep or Path(tempfile.mkdtemp(prefix="zipon-scene-"))
    root.mkdir(parents=True, exist_ok=True)
    params = write_params(root, 1, args.frames, args.width, args.height)
    if args.chunk_frames:
        import yaml

        params.write_text(yaml.safe_dump({**yaml.safe_load(params.read_text()), "maps": {"chunk_frames": args.chunk_frames}},
                                         sort_keys=False))
    scene = "sim_00"
    emit(bench="batch", kind="setup", mode="within_scene", frames=args.frames, size=[args.width, args.height],
         map_stages=args.map_stages, cpus=os.cpu_count(), root=str(root))
    try:
        t_up, _ = zipon(params, "run", "--stage", "simulate", "--stage", "ingest", "--stage", "reconstruct")
        emit(bench="batch", kind="upstream_built", seconds=round(t_up, 1), timed=False)
        digests = {}
        for workers in args.workers:
            stage_args = sum((["--stage", s] for s in args.map_stages), [])
            cpu0 = _children_cpu_s()
            wall, peak = zipon(params, "-S", f"run.workers={workers}", "-S", "run.map_fold_cache=false",
                               "run", "--force", *stage_args)
            cpu = _children_cpu_s() - cpu0
            for stage in args.map_stages:
                m = json.loads((root / "manifests" / scene / f"{stage}.json").read_text())
                digests.setdefault(stage, set()).add(m["outputs"][stage]["digest"])
                emit(bench="batch", kind="map_stage", workers=workers, stage=stage, frames=args.frames,
                     stage_wall_s=m["timing"]["seconds"], chunks=m["summary"]["chunks"],
                     chunk_frames=m["params"]["maps.chunk_frames"])
            emit(bench="batch", kind="map_run", workers=workers, stages=args.map_stages, wall_s=round(wall, 1),
                 cpu_s_all_processes=round(cpu, 1), peak_rss_mb_largest_process=round(peak, 1),
                 frames_per_s=round(args.frames * len(args.map_stages) / wall, 2))
        emit(bench="batch", kind="map_digests", same_for_every_worker_count={s: len(d) == 1 for s, d in digests.items()})
        if args.append:
            for stage in args.map_stages:
                emit(bench="batch", kind="incremental", **incremental_rerun(params, root, scene, stage, args.append))
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


# ----------------------------------------------------------------------------- main

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--frames", type=int, default=1416, help="frames per scene")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--target-frames", type=int, default=14_159, help="frames of the batch the rate is projected to")
    ap.add_argument("--kernel-frames", type=int, default=0,
                    help="frames of the first scene the open3d integrate kernel is timed on (0: all)")
    ap.add_argument("--stages", nargs="+", default=list(STAGES), choices=STAGES, help="stages to time (default: all)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="work in this folder and keep it (default: a temp dir); logs already there are reused (even "
                    "when zipon's code changed since: they are not timed)")
    ap.add_argument("--alone", nargs="*", default=None, metavar="SCENE",
                    help="after the batch runs, run these scenes again one at a time on 1 worker and print each "
                    "stage's CPU seconds in the last batch run over alone, for the same scene (default: the first "
                    "scene when there are several; none: --alone with no name)")
    ap.add_argument("--within-scene", action="store_true",
                    help="one scene's map stages with each worker count, then the incremental rerun (see above)")
    ap.add_argument("--map-stages", nargs="+", default=["vlmap"], choices=("vlmap", "cfmap"),
                    help="--within-scene: the map stages to run")
    ap.add_argument("--chunk-frames", type=int, default=None, help="--within-scene: maps.chunk_frames (default: params')")
    ap.add_argument("--append", type=int, default=200,
                    help="--within-scene: frames appended for the incremental rerun (0 = skip it)")
    ap.add_argument("--real-encoders", action="store_true",
                    help="one scene's map stage with each real encoder (random weights) at its default size: the "
                    "encoder's share and frames/s per encoder (see above)")
    ap.add_argument("--lseg-frames", type=int, default=4,
                    help="--real-encoders: frames LSeg maps (the public ViT-L/16 takes tens of CPU seconds a frame)")
    ap.add_argument("--device", default="cpu", help="--real-encoders: run.device of the encoders (cpu, cuda, cuda:N)")
    ap.add_argument("--precision", default="fp32", choices=("fp32", "bf16", "fp16"),
                    help="--real-encoders: run.precision (autocast of the forward passes)")
    ap.add_argument("--encoders", nargs="+", default=["maskclip", "lseg"], choices=("maskclip", "lseg", "conceptfusion"),
                    help="--real-encoders: the encoders to measure")
    args = ap.parse_args()
    if args.real_encoders:
        args.frames = 16 if args.frames == 1416 else args.frames
        real_encoders(args)
        return
    if args.within_scene:
        args.frames = 1400 if args.frames == 1416 else args.frames
        within_scene(args)
        return

    import torch

    torch.set_num_threads(1)
    root = args.keep or Path(tempfile.mkdtemp(prefix="zipon-batch-"))
    root.mkdir(parents=True, exist_ok=True)
    params = write_params(root, args.scenes, args.frames, args.width, args.height)
    scenes = [f"sim_{i:02d}" for i in range(args.scenes)]
    emit(bench="batch", kind="setup", scenes=args.scenes, frames_per_scene=args.frames, size=[args.width, args.height],
         cpus=os.cpu_count(), root=str(root))
    kept = all((root / "manifests" / s / "simulate.json").is_file() for s in scenes)
    if kept:  # the logs are not what is timed: reuse them even when zipon's code changed since they were written
        emit(bench="batch", kind="logs_reused", root=str(root), timed=False)
    else:
        t_logs, _ = zipon(params, "run", "--stage", "simulate")
        emit(bench="batch", kind="logs_written", seconds=round(t_logs, 1), timed=False)

    from pipeline.paramsfile import load_params
    from pipeline.paths import FOLD

    p = load_params(params)
    h, w = p.encoders.oracle.out_size
    total = args.scenes * args.frames
    data = root / "data"
    logs = sorted((data / "raw").glob("*.mcap"))
    zstd_s, zstd_cpu = kernel_zstd(logs)
    floor = kernel_ingest_floor(logs, root, p.ingest.compression_level)
    parts = ("read", "parse", "encode", "hash")
    floor_s = sum(floor[k] for k in parts)
    emit(bench="batch", kind="ingest_floor", s_per_frame={k: round(floor[k] / total, 6) for k in parts},
         total_s_per_frame=round(floor_s / total, 6), cpu_s_per_frame=round(floor["cpu"] / total, 6),
         images=floor["images"], frames=total, zstd_decode_s_per_frame=round(zstd_s / total, 6))
    # stage -> (wall, CPU) seconds per frame of its bare kernel; a stage's CPU seconds are compared with the
    # kernel's CPU seconds, steadier than wall time on a shared machine
    kernels = {"zstd_decode": (zstd_s / total, zstd_cpu / total), "ingest_floor": (floor_s / total, floor["cpu"] / total),
               "index_add": kernel_index_add(h, w, p.encoders.oracle.dim)}
    first = True
    try:
        for workers in args.workers:
            run_args = ["-S", f"run.workers={workers}", "run", "--force", *sum((["--stage", s] for s in args.stages), [])]
            for fold in data.glob(FOLD.format(scene="*", stage="*")):  # each run a first build: no fold reused
                shutil.rmtree(fold)
            cpu0 = _children_cpu_s()
            wall, peak = zipon(params, *run_args)
            cpu_run = _children_cpu_s() - cpu0  # every process of the run (scheduler, workers), all their threads
            if first:  # frames.zarr exists now: time open3d alone on the first scene's frames
                secs, cpu_k, n = kernel_integrate(params, data / "artifacts" / scenes[0] / "frames.zarr",
                                                  args.kernel_frames)
                kernels["o3d_integrate"] = (secs / n, cpu_k / n)
                emit(bench="batch", kind="kernels", s_per_frame={k: round(v[0], 6) for k, v in kernels.items()},
                     cpu_s_per_frame={k: round(v[1], 6) for k, v in kernels.items()},
                     kernel_frames={"zstd_decode": total, "ingest_floor": total, "o3d_integrate": n, "index_add": 16},
                     feature_rows=[h * w, p.encoders.oracle.dim])
                for kind in ("vlmap", "cfmap"):
                    if kind in args.stages:
                        share = encoder_share(params, root, scenes[0], kind)
                        # the stage's own CPU a frame (in this process, nothing else running) over its kernel's:
                        # the map stages' honest ratio (the per-stage lines below are upper bounds under processes)
                        own = share["stage_cpu_s"] / args.frames / kernels["index_add"][1]
                        emit(bench="batch", kind="encoder_share", scene=scenes[0], frames=args.frames, **share,
                             kernel="index_add", stage_cpu_ratio_to_kernel=round(own, 2))
                first = False
            timing = manifests(root, scenes, args.stages)
            for stage in args.stages:
                t = timing[stage]
                waited = sum(x.get("waited_seconds", 0.0) for x in t)  # map stages standing in line for a turn
                secs = sum(x["seconds"] for x in t) - waited
                cpu = sum(x.get("cpu_seconds", float("nan")) for x in t)
                row = {"bench": "batch", "kind": "stage", "workers": workers, "stage": stage,
                       "frames_per_s": round(total / secs, 2), "wall_s": round(secs, 2), "waited_s": round(waited, 2),
                       "cpu_s": round(cpu, 2),
                       "cpu_frames_per_s": round(total / cpu, 2) if cpu == cpu else None,
                       "peak_rss_mb": round(max(x.get("peak_rss_mb", float("nan")) for x in t), 1)}
                counters = [x.get("counters", {}) for x in t]  # the worker's faults, switches and reads, per frame
                for key, scale in (("minor_faults", 1), ("major_faults", 1), ("preempted", 1),
                                   ("read_bytes", 1 << 20), ("disk_read_bytes", 1 << 20)):
                    if all(key in c for c in counters):
                        name = key.replace("_bytes", "_mb")
                        row[f"{name}_per_frame"] = round(sum(c[key] for c in counters) / scale / total, 3)
                kernel = KERNEL_OF.get(stage)
                if kernel:
                    row["kernel"] = kernel
                    row["ratio_to_kernel"] = round(secs / total / kernels[kernel][0], 2)
                    row["cpu_ratio_to_kernel"] = round(cpu / total / kernels[kernel][1], 2) if cpu == cpu else None
                emit(**row)
            rate = total / wall
            # the wall time the stages' bare kernels alone imply (CPU seconds a frame of each stage's kernel, summed
            # over the stages run, x target frames / cores): no scheduling, no I/O beyond the kernels', perfect
            # balance. A target below it needs less work per frame, not a faster run of the same work.
            floor_cpu = sum(kernels[KERNEL_OF[s]][1] for s in args.stages if s in KERNEL_OF)
            emit(bench="batch", kind="run", workers=workers, frames=total, wall_s=round(wall, 1),
                 kernel_floor_wall_min_for_target=round(
                     args.target_frames * floor_cpu / min(workers, os.cpu_count() or 1) / 60, 1),
                 frames_per_s=round(rate, 2), peak_rss_mb_largest_process=round(peak, 1),
                 projected_wall_min_for_target=round(args.target_frames / rate / 60, 1),
                 cpu_s=round(cpu_run, 1), projected_wall_min_if_cpu_bound=round(
                     args.target_frames * cpu_run / total / min(workers, os.cpu_count() or 1) / 60, 1),
                 target_frames=args.target_frames)
        alone = args.alone if args.alone is not None else (scenes[:1] if len(scenes) > 1 else [])
        if alone:
            batch = manifests(root, alone, args.stages)
            batch_workers = args.workers[-1]
            for i, scene in enumerate(alone):
                run_args = ["-S", "run.workers=1", "run", "--force", "-s", scene,
                            *sum((["--stage", s] for s in args.stages), [])]
                for fold in data.glob(FOLD.format(scene=scene, stage="*")):
                    shutil.rmtree(fold)
                cpu0 = _children_cpu_s()
                wall, _ = zipon(params, *run_args)
                cpu_alone_run = _children_cpu_s() - cpu0
                single = manifests(root, [scene], args.stages)
                cpu = {stage: (batch[stage][i].get("cpu_seconds", 0.0), single[stage][0].get("cpu_seconds", 0.0))
                       for stage in args.stages}  # stage -> (in the batch, alone)
                per_stage = {stage: {"batch_cpu_s": b, "alone_cpu_s": a, "ratio": round(b / a, 3) if a else None}
                             for stage, (b, a) in cpu.items()}
                b_sum, a_sum = (sum(pair[k] for pair in cpu.values()) for k in (0, 1))
                emit(bench="batch", kind="batch_vs_alone", scene=scene, batch_workers=batch_workers,
                     stages=per_stage, stages_cpu_ratio=round(b_sum / a_sum, 3) if a_sum else None,
                     alone_run_wall_s=round(wall, 1), alone_run_cpu_s=round(cpu_alone_run, 1))
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
