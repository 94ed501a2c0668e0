"""Ingest throughput and memory: ROS 2 MCAP logs of 140 and 1,400 frames at 480x640.

Frames come from the simulator (``pipeline.sim``: ``--sim-frames`` rendered frames, cycled to the log
length, since rendering is the slow part and not what is measured) or, with ``--synthetic``, from
smooth synthetic images. Each log size is written and ingested in its own subprocess, so peak RSS
(``ru_maxrss``) is per size: equal figures show memory independent of log length. The same run
compares the two ways of decoding ``sensor_msgs/Image``: the numpy CDR parser the reader uses, and
``mcap_ros2``'s generic decoder, and the readers: the MCAP fast path (``mcap``) against ``rosbags``
reading the same log as ``.mcap``, as a ROS 1 ``.bag`` and as a ROS 2 ``.db3`` (converted with
``rosbags.convert``), and the same frames written as 7-Scenes, TUM, Replica and ScanNet folders (by the
test fixtures' writers, ``tests/fixtures/raw_datasets.py``). One JSON object per line on stdout.

    .venv/bin/python benchmarks/bench_ingest.py [--sizes 140 1400] [--transport raw|compressed]
        [--codecs zstd lz4] [--readers mcap rosbag-mcap rosbag-ros1 rosbag-db3 7scenes tum replica scannet]
        [--synthetic]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import ROOT, emit, peak_rss_mb

H, W, FPS = 480, 640, 10.0


def make_frames(out: Path, n_unique: int, synthetic: bool) -> str:
    """Save ``n_unique`` frames (rgb, depth_mm, instance) to ``out`` (npz); returns their origin."""
    if not synthetic:
        try:
            from pipeline.config import SimulateParams
            from pipeline.sim import SceneRaycaster, SimulatedRecording

            p = SimulateParams(frames=n_unique, width=W, height=H)
            rec = SimulatedRecording("bench", p)
            blocks = list(rec.blocks(SceneRaycaster(rec.gt, rec.intrinsics)))
            np.savez(out, rgb=np.concatenate([b[1] for b in blocks]), depth=np.concatenate([b[2] for b in blocks]),
                     instance=np.concatenate([b[3] for b in blocks]))
            return f"pipeline.sim ({n_unique} rendered frames, cycled)"
        except ImportError:
            pass
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    rgb, depth, inst = [], [], []
    for i in range(n_unique):
        a = 2 * np.pi * i / n_unique
        rgb.append(np.stack([(127 + 120 * np.sin(u / 40 + a)), (127 + 120 * np.cos(v / 30 - a)),
                             (u + v + 10 * i) % 256], -1).astype(np.uint8))
        depth.append((1500 + 1000 * np.sin(u / 90 + a) + 5 * v).astype(np.uint16))
        inst.append(((u // 80 + v // 60 + i) % 12).astype(np.uint16))
    np.savez(out, rgb=np.stack(rgb), depth=np.stack(depth), instance=np.stack(inst))
    return f"synthetic ({n_unique} frames, cycled)"


# ----------------------------------------------------------------------------- children

def child_write(frames: Path, n: int, log: Path, transport: str) -> dict:
    from pipeline.geometry import Intrinsics, camera_pose_from_base
    from pipeline.ros2 import Ros2LogWriter

    data = np.load(frames)
    rgb, depth, inst = data["rgb"], data["depth"], data["instance"]
    t0 = time.perf_counter()
    start = 1_704_067_200 * 10**9
    pose_dt = int(1e9 / 30.0)
    with Ros2LogWriter(log, intrinsics=Intrinsics.from_hfov(W, H, 90.0), image_transport=transport,
                       pose_topic_kind="tf") as w:
        next_pose = 0
        for i in range(n):
            stamp = start + int(round(i * 1e9 / FPS))
            while start + next_pose * pose_dt <= stamp + pose_dt:  # poses at 30 Hz, bracketing every frame
                t = next_pose * pose_dt * 1e-9
                w.write_pose(start + next_pose * pose_dt, camera_pose_from_base(0.2 * t, 0.0, 0.3 * t, 0.88))
                next_pose += 1
            k = i % len(rgb)
            w.write_frame(stamp, rgb[k], depth[k], inst[k])
    s = time.perf_counter() - t0
    return {"what": "write", "frames": n, "transport": transport, "seconds": round(s, 2),
            "frames_per_s": round(n / s, 1), "log_mb": round(log.stat().st_size / 2**20, 1)}


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def child_convert(log: Path, out: Path, kind: str) -> dict:
    """The MCAP log as a ROS 1 ``.bag`` or a ROS 2 ``.db3`` bag folder (``rosbags.convert``)."""
    from rosbags.convert import convert

    t0 = time.perf_counter()
    convert([log], out, dst_storage="sqlite3", dst_version=9, compress=None, compress_mode="file",
            default_typestore=None, typestore=None, exclude_topics=[], include_topics=[], exclude_msgtypes=[],
            include_msgtypes=[])
    size = sum(f.stat().st_size for f in ([out] if out.is_file() else out.rglob("*")) if f.is_file())
    return {"what": "convert", "to": kind, "seconds": round(time.perf_counter() - t0, 2),
            "bag_mb": round(size / 2**20, 1)}


class _Cycled:
    """Frame ``i`` of ``n`` is ``frames[i % len(frames)]``, without materialising ``n`` frames."""

    def __init__(self, frames: np.ndarray, n: int):
        self.frames, self.n = frames, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> np.ndarray:
        return self.frames[i % len(self.frames)]


def child_folder(frames: Path, n: int, out: Path, fmt: str) -> dict:
    """Write ``n`` frames as a ``fmt`` dataset folder with the test fixtures' writers; returns its path."""
    from pipeline.geometry import Intrinsics
    from tests.fixtures import raw_datasets as rd

    data = np.load(frames)
    stamps = rd.T0_NS + np.round(np.arange(n) * 1e9 / FPS).astype(np.int64)
    rec = rd.Recording(_Cycled(data["rgb"], n), _Cycled(data["depth"], n), _Cycled(data["instance"], n),
                       rd.trajectory((stamps - rd.T0_NS) * 1e-9), stamps, Intrinsics.from_hfov(W, H, 90.0))
    writers = {"7scenes": rd.write_7scenes, "tum": rd.write_tum, "replica": rd.write_replica,
               "scannet": rd.write_scannet}
    t0 = time.perf_counter()
    root = writers[fmt](out, rec)
    return {"what": "write_folder", "format": fmt, "frames": n, "seconds": round(time.perf_counter() - t0, 2),
            "path": str(root)}


def child_ingest(log: Path, out: Path, n: int, codec: str, fmt: str = "auto") -> dict:
    """Ingest ``log``; wall and CPU time (the machine may be shared: CPU seconds per frame is the stable figure)."""
    from pipeline.config import IngestParams
    from pipeline.readers.ingest import ingest_path

    rss0 = peak_rss_mb()
    t0, c0 = time.perf_counter(), _cpu_s()
    summary = ingest_path(log, out, IngestParams(codec=codec), fmt, log=lambda m: None)
    s, cpu = time.perf_counter() - t0, _cpu_s() - c0
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    m = summary["matched_frames"]
    return {"what": "ingest", "reader": fmt, "frames": n, "codec": codec, "matched_frames": m, "seconds": round(s, 2),
            "frames_per_s": round(m / s, 1), "cpu_ms_per_frame": round(cpu * 1e3 / m, 2),
            # upper bound on 2 idle cores: reading and compressing/writing overlap in two threads
            "frames_per_s_cpu_bound_2_cores": round(2.0 * m / cpu, 1),
            "peak_rss_mb": round(peak_rss_mb(), 1), "rss_after_imports_mb": round(rss0, 1),
            "frames_zarr_mb": round(size / 2**20, 1)}


def child_decode(log: Path, n: int) -> dict:
    """Per-message decode cost of the image topics: numpy CDR parser vs mcap_ros2's generic decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from pipeline.ros2 import parse_image_cdr, raw_image_to_array

    topics = ["/camera/color/image_raw", "/camera/depth/image_raw"]
    out = {"what": "decode_sensor_msgs_Image", "messages": 0}
    with open(log, "rb") as f:
        reader = make_reader(f)
        t0 = time.perf_counter()
        raw = [(ch.topic, m.data) for _, ch, m in reader.iter_messages(topics=topics)]
        out["read_decompress_ms_per_frame"] = round((time.perf_counter() - t0) * 1e3 / n, 3)
    out["messages"] = len(raw)
    t0 = time.perf_counter()
    for _, data in raw:
        raw_image_to_array(parse_image_cdr(data), where={})
    out["numpy_cdr_ms_per_frame"] = round((time.perf_counter() - t0) * 1e3 / n, 3)
    factory = DecoderFactory()
    with open(log, "rb") as f:
        summary = make_reader(f).get_summary()
    schema = next(s for s in summary.schemas.values() if s.name == "sensor_msgs/msg/Image")
    dec = factory.decoder_for("cdr", schema)
    t0 = time.perf_counter()
    for topic, data in raw:
        m = dec(data)
        dt = np.uint16 if m.encoding == "16UC1" else np.uint8
        arr = np.frombuffer(m.data, dt).reshape(m.height, m.width, -1).copy()
    out["mcap_ros2_ms_per_frame"] = round((time.perf_counter() - t0) * 1e3 / n, 3)
    del raw, arr
    return out


def _child(argv: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", *argv], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "OMP_NUM_THREADS": "2"})
    if out.returncode:
        raise SystemExit(f"child {argv} failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


# reader variant -> (container written from the MCAP log, --format)
READERS = {"mcap": (None, "mcap"), "rosbag-mcap": (None, "rosbag"), "rosbag-ros1": ("log.bag", "rosbag"),
           "rosbag-db3": ("log_db3", "rosbag"), "7scenes": ("folder", "7scenes"), "tum": ("folder", "tum"),
           "replica": ("folder", "replica"), "scannet": ("folder", "scannet")}


def compare_readers(tmp: Path, log: Path, n: int, codec: str, names: list[str], mcap_result: dict | None) -> dict:
    """Ingest the same frames through each reader variant; returns name -> ingest result. Folder formats
    synthesise their own stamps (and TUM interpolates poses), so only the reading cost compares."""
    out = {}
    for name in names:
        container, fmt = READERS[name]
        if name == "mcap" and mcap_result is not None:
            out[name] = mcap_result
            continue
        src = log
        if container == "folder":
            written = _child(["folder", str(tmp / "frames.npz"), str(n), str(tmp / f"folder_{name}"), fmt])
            emit(**written)
            src = Path(written["path"])
        elif container:
            src = tmp / container
            emit(**_child(["convert", str(log), str(src), name]))
        res = _child(["ingest", str(src), str(tmp / f"frames_{name}.zarr"), str(n), codec, fmt])
        res["reader"] = name
        out[name] = res
        emit(**res)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[140, 1400])
    ap.add_argument("--transport", choices=["raw", "compressed"], default="raw")
    ap.add_argument("--codecs", nargs="+", choices=["zstd", "lz4"], default=["zstd", "lz4"],
                    help="frames.zarr codecs to ingest with (ingest.codec)")
    ap.add_argument("--readers", nargs="*", choices=list(READERS), default=list(READERS),
                    help="readers compared on the largest log (first codec); mcap is also run per codec")
    ap.add_argument("--synthetic", action="store_true", help="synthetic images instead of pipeline.sim renders")
    ap.add_argument("--sim-frames", type=int, default=24, help="frames rendered by pipeline.sim, cycled")
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        kind, *rest = args.child
        if kind == "write":
            res = child_write(Path(rest[0]), int(rest[1]), Path(rest[2]), rest[3])
        elif kind == "ingest":
            res = child_ingest(Path(rest[0]), Path(rest[1]), int(rest[2]), rest[3], rest[4])
        elif kind == "convert":
            res = child_convert(Path(rest[0]), Path(rest[1]), rest[2])
        elif kind == "folder":
            res = child_folder(Path(rest[0]), int(rest[1]), Path(rest[2]), rest[3])
        elif kind == "frames":
            res = {"origin": make_frames(Path(rest[0]), int(rest[1]), bool(int(rest[2])))}
        else:
            res = child_decode(Path(rest[0]), int(rest[1]))
        print(json.dumps(res))
        return
    with tempfile.TemporaryDirectory(prefix="bench_ingest_") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        origin = _child(["frames", str(tmp / "frames.npz"), str(args.sim_frames), str(int(args.synthetic))])["origin"]
        emit(**{"what": "setup", "frames_from": origin, "seconds": round(time.perf_counter() - t0, 1),
                "cpus": os.cpu_count(), "size": f"{W}x{H}"})
        results, readers = {}, {}
        for n in args.sizes:
            log = tmp / f"log_{n}.mcap"
            emit(**_child(["write", str(tmp / "frames.npz"), str(n), str(log), args.transport]))
            for codec in args.codecs:
                res = _child(["ingest", str(log), str(tmp / f"frames_{n}_{codec}.zarr"), str(n), codec, "mcap"])
                results[(n, codec)] = res
                emit(**res)
            if n == max(args.sizes) and args.transport == "raw":
                emit(**_child(["decode", str(log), str(n)]))
            if n == max(args.sizes):
                readers = compare_readers(tmp, log, n, args.codecs[0], args.readers, results.get((n, args.codecs[0])))
            log.unlink()
        lo, hi = min(args.sizes), max(args.sizes)
        for codec in args.codecs:
            a, b = results[(lo, codec)], results[(hi, codec)]
            emit(**{"what": "summary", "codec": codec, "transport": args.transport,
                    "frames_per_s": b["frames_per_s"],
                    "frames_per_s_cpu_bound_2_cores": b["frames_per_s_cpu_bound_2_cores"],
                    "peak_rss_mb": {str(lo): a["peak_rss_mb"], str(hi): b["peak_rss_mb"]},
                    "rss_ratio_long_vs_short": round(b["peak_rss_mb"] / a["peak_rss_mb"], 3),
                    "goal_frames_per_s": 100})
        if readers:
            emit(**{"what": "summary_readers", "frames": hi, "codec": args.codecs[0],
                    "frames_per_s": {k: v["frames_per_s"] for k, v in readers.items()},
                    "cpu_ms_per_frame": {k: v["cpu_ms_per_frame"] for k, v in readers.items()}})


if __name__ == "__main__":
    main()
