"""Images/s of each encoder on CPU, against the bare model forward it wraps, in the same run.

Prints one JSON object per line. Every encoder is built through ``build_encoder`` from random-init
weights saved to a temporary file (nothing is downloaded). References, on the same batch:

- maskclip: the bare open_clip ViT-B-32 ``encode_image`` at the same input size (same token count);
- conceptfusion: the bare ``encode_image`` on the same number of 224 px crops (global + regions),
  with region generation timed separately (it is part of the method, not wrapper overhead);
- lseg: the bare ``LSegNet.encode_image`` on the same sliding-window crops. The public ViT-L/16
  network at 480 px crops takes tens of seconds per frame on 2 cores, so by default a reduced
  network (``--lseg-arch base``: ViT-B/16-sized backbone, same layout) is measured; ``--lseg-arch
  full`` measures the public size;
- oracle: no model (a ground-truth lookup).

Each encoder/reference pair runs back to back ``--repeat`` times; ``overhead_pct`` is the median
ratio of their CPU times (the machine is shared, so wall times drift), ``pair_ratios`` lists all.

Usage: ``python benchmarks/bench_encoders.py [--threads 2] [--batch 4] [--images 8] [--only maskclip,...]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
import numpy as np
import open_clip
import torch
from _common import emit

from pipeline.config import EncodersParams, RunParams
from pipeline.encoders import build_encoder
from pipeline.encoders.lseg import LSegEncoder, load_lseg_net
from pipeline.encoders.lseg_net import LSEG_VITL16_384, LSegArch, LSegNet


def frames(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """480x640 frames of coloured boxes at several depths, with instance ids (a synthetic indoor-like view)."""
    rng = np.random.default_rng(seed)
    H, W = 480, 640
    rgb = np.empty((n, H, W, 3), np.uint8)
    depth = np.empty((n, H, W), np.float32)
    inst = np.zeros((n, H, W), np.uint16)
    for b in range(n):
        rgb[b] = rng.integers(60, 120, 3)
        depth[b] = np.linspace(5.0, 1.0, H, dtype=np.float32)[:, None]
        for k in range(1, 13):
            y0, x0 = rng.integers(0, H - 80), rng.integers(0, W - 80)
            y1, x1 = y0 + rng.integers(40, 200), x0 + rng.integers(40, 240)
            rgb[b, y0:y1, x0:x1] = rng.integers(0, 255, 3)
            depth[b, y0:y1, x0:x1] = rng.uniform(1, 4)
            inst[b, y0:y1, x0:x1] = k
        rgb[b] = np.clip(rgb[b].astype(np.int16) + rng.integers(-6, 7, (H, W, 3)), 0, 255)
    return rgb, depth, inst


def timed(fn, repeat: int = 1, clock=time.perf_counter) -> float:
    """Best time of ``repeat`` runs, seconds, on ``clock``."""
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        with torch.inference_mode():
            fn()
        best = min(best, clock() - t0)
    return best


def paired(fn_encoder, fn_reference, repeat: int) -> dict[str, float]:
    """Encoder vs reference, run alternately ``repeat`` times: best wall / CPU seconds of each, and the
    median of the per-pair CPU-time ratios.

    The machine is shared: wall times drift with other people's load, so runs are interleaved, the
    CPU time this process used (all its threads) is measured too, and the overhead is the median
    ratio of back-to-back pairs (robust to drift between pairs).
    """
    t = {"enc_wall": float("inf"), "ref_wall": float("inf"), "enc_cpu": float("inf"), "ref_cpu": float("inf")}
    ratios = []
    for _ in range(repeat):
        pair = {}
        for key, fn in (("enc", fn_encoder), ("ref", fn_reference)):
            w0, c0 = time.perf_counter(), time.process_time()
            with torch.inference_mode():
                fn()
            pair[key] = time.process_time() - c0
            t[f"{key}_wall"] = min(t[f"{key}_wall"], time.perf_counter() - w0)
            t[f"{key}_cpu"] = min(t[f"{key}_cpu"], pair[key])
        ratios.append(pair["enc"] / pair["ref"])
    t["ratio"] = float(np.median(ratios))
    t["ratios"] = [round(r, 3) for r in ratios]
    return t


def figures(n: int, t: dict, extra_cpu: float = 0.0) -> dict:
    """Images/s (wall) of both, CPU seconds per image of both, overhead % (median pair ratio of CPU time)."""
    return {
        "images_per_s": round(n / t["enc_wall"], 4),
        "reference_images_per_s": round(n / t["ref_wall"], 4),
        "cpu_s_per_image": round(t["enc_cpu"] / n, 4),
        "reference_cpu_s_per_image": round(t["ref_cpu"] / n, 4),
        "overhead_pct": round(100 * (t["ratio"] - 1), 1),
        "pair_ratios": t["ratios"],
        **({"region_share_pct": round(100 * extra_cpu / t["enc_cpu"], 1)} if extra_cpu else {}),
    }


def runtime(args) -> RunParams:
    """The run settings the encoders are timed with: CPU, the chosen batch size and threads."""
    return RunParams(device="cpu", encoder_batch_size=args.batch, torch_threads=args.threads)


def bench_maskclip(weights: Path, args, rgb) -> None:
    p = EncodersParams(maskclip={"arch": "ViT-B-32", "weights": str(weights)})
    enc = build_encoder(p, "maskclip", runtime=runtime(args))
    bare = open_clip.create_model("ViT-B-32", pretrained=None, force_image_size=(480, 640)).eval()
    x = torch.cat([enc.preprocess(rgb[i : i + args.batch]) for i in range(0, len(rgb), args.batch)])
    enc.encode_images(rgb[: args.batch])  # warm-up
    t = paired(lambda: enc.encode_images(rgb),
               lambda: [bare.encode_image(x[i : i + args.batch]) for i in range(0, len(x), args.batch)], args.repeat)
    t_prep = timed(lambda: [enc.preprocess(rgb[i : i + args.batch]) for i in range(0, len(rgb), args.batch)])
    emit(encoder="maskclip", model="ViT-B-32", input="480x640", feature_grid=list(enc.encode_images(rgb[:1]).size),
         images=len(rgb), batch_size=args.batch, threads=torch.get_num_threads(),
         reference="open_clip encode_image, same ViT at 480x640 (300 tokens)", preprocess_s=round(t_prep, 3),
         **figures(len(rgb), t))


def bench_conceptfusion(weights: Path, args, rgb, depth, inst) -> None:
    for gen in ("rgbd", "gt"):
        p = EncodersParams(conceptfusion={"arch": "ViT-B-32", "weights": str(weights), "regions": {"generator": gen}})
        enc = build_encoder(p, "conceptfusion", runtime=runtime(args))
        regions = [enc.regions(rgb[i], depth[i], inst[i]) for i in range(len(rgb))]
        n_crops = sum(len(r) + 1 for r in regions)
        # the same crop batches the encoder runs: per batch of frames, 64 crops per pass
        per_batch = [sum(len(r) + 1 for r in regions[i : i + args.batch]) for i in range(0, len(rgb), args.batch)]
        crop_sets = [torch.rand(n, 3, 224, 224) for n in per_batch]
        t_regions = timed(lambda: [enc.regions(rgb[i], depth[i], inst[i]) for i in range(len(rgb))],
                          clock=time.process_time)
        enc.encode_images(rgb[:1], depth_m=depth[:1], instance=inst[:1])  # warm-up
        t = paired(lambda: enc.encode_images(rgb, depth_m=depth, instance=inst),
                   lambda: [enc.model.encode_image(c[i : i + 64]) for c in crop_sets for i in range(0, len(c), 64)],
                   args.repeat)
        emit(encoder="conceptfusion", regions=gen, model="ViT-B-32", input="480x640", images=len(rgb),
             batch_size=args.batch, threads=torch.get_num_threads(), crops=n_crops,
             region_generation_cpu_s=round(t_regions, 3),
             reference="open_clip encode_image on the same 224 px crop batches (64 per pass)",
             **figures(len(rgb), t, extra_cpu=t_regions))


def bench_lseg(tmp: Path, args, rgb) -> None:
    if args.lseg_arch == "full":
        arch, crop, name = LSEG_VITL16_384, 480, "clip_vitl16_384 (public size)"
    else:
        arch = LSegArch(vit_width=768, vit_depth=12, vit_heads=12, hooks=(2, 5, 8, 11),
                        post_channels=(96, 192, 384, 768), name="reduced ViT-B/16-sized backbone")
        crop, name = 480, arch.name
    torch.manual_seed(0)
    path = tmp / "lseg.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in LSegNet(arch).state_dict().items()}}, path)
    enc = LSegEncoder(load_lseg_net(path, arch), weights=path, crop_size=crop, base_size=520,
                      batch_size=args.batch)
    n = min(len(rgb), args.lseg_images)
    sub = rgb[:n]
    windows = torch.randn(2 * n, 3, crop, crop)  # 480x640 -> 390x520 -> two 480 px windows per frame
    t = paired(lambda: enc.encode_images(sub),
               lambda: [enc.net.encode_image(windows[i : i + args.batch]) for i in range(0, len(windows), args.batch)],
               args.repeat)
    emit(encoder="lseg", network=name, crop=crop, base_size=520, windows_per_image=2, images=n,
         batch_size=args.batch, threads=torch.get_num_threads(),
         reference="bare LSegNet.encode_image on the same number of 480 px windows", **figures(n, t))


def bench_oracle(args, rgb, inst) -> None:
    from tests.pipeline.encoders.conftest import gt_scene

    enc = build_encoder(EncodersParams(), "oracle", runtime=runtime(args))
    enc.bind_scene(gt_scene())
    t = timed(lambda: enc.encode_images(rgb, instance=np.minimum(inst, 3)), args.repeat)
    emit(encoder="oracle", images=len(rgb), batch_size=args.batch, threads=torch.get_num_threads(),
         out_size=[120, 160], images_per_s=round(len(rgb) / t, 2), reference=None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--images", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--lseg-arch", choices=["base", "full"], default="base")
    ap.add_argument("--lseg-images", type=int, default=2)
    ap.add_argument("--only", default="maskclip,conceptfusion,lseg,oracle")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    only = set(args.only.split(","))
    rgb, depth, inst = frames(args.images)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        weights = tmp / "vitb32.pt"
        torch.manual_seed(0)
        torch.save(open_clip.create_model("ViT-B-32", pretrained=None).state_dict(), weights)
        if "maskclip" in only:
            bench_maskclip(weights, args, rgb)
        if "conceptfusion" in only:
            bench_conceptfusion(weights, args, rgb, depth, inst)
        if "lseg" in only:
            bench_lseg(tmp, args, rgb)
        if "oracle" in only:
            bench_oracle(args, rgb, inst)


if __name__ == "__main__":
    main()
