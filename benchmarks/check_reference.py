"""zipon's real encoders against their reference implementations, with the same random weights.

No trained LSeg / CLIP weights can be had here, so exactness is shown the other way: one random-init model is
saved to a file, loaded by zipon and by the reference's own code, both run on the same real TUM RGB-D frame
(``tests/data/tum_fr1_rpy_head30``, first frame, 480x640), and the largest absolute difference of the
unit-norm features is printed, one JSON line per encoder (``max_abs_diff``, ``ok`` = within ``--tol``, 1e-4).

- ``lseg``: isl-org/lang-seg (``modules/models/lseg_net.py`` ``LSegNet``, timm ``vit_large_patch16_384`` backbone,
  DPT decoder) on the sliding windows zipon's LSeg encoder cuts from the frame (crop ``--lseg-crop`` px). The
  reference's per-pixel features are the output of its ``scratch.head1`` (read with a forward hook while its own
  ``forward`` runs), L2-normalised as its ``forward`` does; zipon's are ``LSegNet.encode_image`` of the same windows.
- ``maskclip``: MaskCLIP (chongzhou/MaskCLIP; mmseg ``VisionTransformer`` with ``return_qkv`` on the last layer +
  ``MaskClipHead``, config ``configs/_base_/models/maskclip_vit16.py``), weights converted by its own
  ``tools/maskclip_utils/convert_clip_weights.py``, run on the tensor zipon feeds its ViT (CLIP-normalised
  480x640); the reference's features are the head's ``proj`` output (forward hook), L2-normalised as its
  ``cls_seg`` does. Arch: open_clip ``ViT-B-16`` (MaskCLIP's config: ViT-B/16, exact GELU).
- ``conceptfusion``: concept-fusion ``examples/extract_conceptfusion_features.py`` ``main()`` run end to end on
  the frame, SAM replaced by the masks of zipon's own region proposer (``rgbd`` at full resolution) followed by
  ``MERGED`` unions of pairs of them (SAM's masks overlap; this exercises the in-order renormalisation), the same
  masks in the same order given to zipon's encoder; both write features at the image's own size (the
  reference's last 'nearest' resize is then the identity). Its ViT-H-14 is replaced by the random ViT-B-32 both
  load. The reference accumulates and stores its features in fp16, so two lines are printed: ``conceptfusion``
  (the reference as published; it rounds a cell's feature to fp16 three times, each by up to half a spacing, so
  its tolerance is the larger of ``--tol`` and 1.5 fp16 spacings at the largest feature value,
  ``fp16_spacing_at_peak``) and ``conceptfusion_fp32`` (the same run with its fp16 casts, ``.half()`` and
  ``dtype=torch.half``, kept in fp32: its fusion rule at zipon's precision, tolerance ``--tol``).

Shims (the references' algorithms run unchanged; only what cannot be imported or downloaded here is replaced):

- ``clip`` (OpenAI's package, not installable offline): ``clip.load(name)`` returns the random open_clip model of
  the same architecture (QuickGELU, fp16 on 'cuda' as ``clip.load`` does), ``clip.tokenize`` = open_clip's;
- ``timm.create_model(..., pretrained=True)`` is called with ``pretrained=False`` (no download; the weights are
  then loaded from the random checkpoint, strictly);
- mmcv's compiled ops (``mmcv._ext``; mmcv is installed without them, ``MMCV_WITH_OPS=0``): a stand-in module
  whose ops raise if called, so that ``import mmseg.models`` (its losses import ``mmcv.ops``) works; no op is
  called on this path. ``torch.load(map_location='cuda')`` in ``MaskClipHead.load_visual_projs`` maps to the CPU;
- concept-fusion: ``gradslam`` (datasets: one frame's path), ``segment_anything`` (returns the given masks), ``tyro``
  (the program's arguments), ``open_clip.create_model_and_transforms`` (the random model + open_clip's own eval
  transform), ``.cuda()`` returns the CPU tensor/module.

Reference packages (the versions they pin, installed OUTSIDE the project venv, e.g. into /tmp/zipon-refdeps, and
put on the path with ``--refdeps``): ``timm==0.4.12`` (lang-seg), ``mmcv==1.5.0`` built with ``MMCV_WITH_OPS=0``
(MaskCLIP's mmseg accepts mmcv 1.3.13-1.5.0; ``pip wheel`` it with setuptools<70), ``addict``, ``yapf``.

Usage (clones of the references, checked out anywhere outside the repository; never commit them)::

    HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/check_reference.py --lseg /tmp/ref/lang-seg \\
        --maskclip /tmp/ref/MaskCLIP --conceptfusion /tmp/ref/concept-fusion --refdeps /tmp/zipon-refdeps

Exit status: 0 when every encoder checked is within tolerance, 1 when one is not, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import runpy
import subprocess
import sys
import tempfile
import time
import types
import warnings
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FRAMES = ROOT / "tests" / "data" / "tum_fr1_rpy_head30"
FP16_ROUNDINGS = 3  # conceptfusion: fp16 roundings on the reference's path of a cell's feature
MERGED = 8  # conceptfusion: overlapping masks added (unions of pairs of proposer regions)
REFERENCES = {  # name -> (reference repository, a file its clone must have)
    "lseg": ("isl-org/lang-seg", "modules/models/lseg_net.py"),
    "maskclip": ("chongzhou/MaskCLIP", "mmseg/models/decode_heads/maskclip_head.py"),
    "conceptfusion": ("concept-fusion/concept-fusion", "examples/extract_conceptfusion_features.py"),
}


class UsageError(Exception):
    """A bad command line or input folder: printed as ``check_reference.py: error: ...``, exit status 2."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    for name, (repo, _) in REFERENCES.items():
        ap.add_argument(f"--{name}", type=Path, metavar="PATH", help=f"a local clone of {repo}")
    ap.add_argument("--frames", type=Path, default=DEFAULT_FRAMES, help="a TUM RGB-D folder (rgb.txt, depth.txt)")
    ap.add_argument("--frame-index", type=int, default=0, help="which rgb.txt entry")
    ap.add_argument("--refdeps", type=Path, help="a folder with the references' pinned packages, put first on the path")
    ap.add_argument("--lseg-crop", type=int, default=480, help="LSeg sliding-window crop, px (multiple of 32)")
    ap.add_argument("--tol", type=float, default=1e-4, help="largest max-abs difference accepted")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = ap.parse_args(argv)
    chosen = [n for n in REFERENCES if getattr(args, n) is not None]
    if not chosen:
        raise UsageError("give at least one of --lseg PATH, --maskclip PATH, --conceptfusion PATH (reference clones)")
    for name in chosen:
        path: Path = getattr(args, name)
        marker = REFERENCES[name][1]
        if not (path / marker).is_file():
            raise UsageError(f"--{name} {path}: not a clone of {REFERENCES[name][0]} ({marker} not found)")
    if not (args.frames / "rgb.txt").is_file():
        raise UsageError(f"--frames {args.frames}: no rgb.txt (a TUM RGB-D folder is expected)")
    if args.refdeps is not None and not args.refdeps.is_dir():
        raise UsageError(f"--refdeps {args.refdeps}: not a folder")
    if args.lseg_crop <= 0 or args.lseg_crop % 32:
        raise UsageError(f"--lseg-crop {args.lseg_crop}: must be a positive multiple of 32")
    args.chosen = chosen
    return args


# ----------------------------------------------------------------------------- inputs and helpers

def _index(path: Path) -> list[tuple[float, str]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            stamp, name = line.split()[:2]
            rows.append((float(stamp), name))
    return rows


def load_frame(folder: Path, index: int):
    """``(rgb (H,W,3) uint8, depth (H,W) float32 metres, rgb file)`` of one TUM frame (depth: nearest stamp)."""
    import cv2
    import numpy as np

    from pipeline.readers.tum import tum_depth_to_mm

    rgbs, depths = _index(folder / "rgb.txt"), _index(folder / "depth.txt")
    if not 0 <= index < len(rgbs):
        raise UsageError(f"--frame-index {index}: {folder / 'rgb.txt'} has {len(rgbs)} frames")
    stamp, name = rgbs[index]
    dname = min(depths, key=lambda r: abs(r[0] - stamp))[1]
    bgr = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
    raw = cv2.imread(str(folder / dname), cv2.IMREAD_UNCHANGED)
    if bgr is None or raw is None:
        raise UsageError(f"{folder}: cannot read {name} or {dname}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), tum_depth_to_mm(raw).astype(np.float32) / 1000.0, folder / name


def commit_of(path: Path) -> str | None:
    try:
        return subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def perturb(model, seed: int) -> None:
    """Random biases, norm scales and batch-norm statistics (default inits leave many of them 0/1, which would
    let a dropped bias or a swapped norm go unseen)."""
    import torch

    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if p.ndim == 1 and p.is_floating_point():
                p.add_(torch.randn(p.shape, generator=g) * 0.05)
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(torch.rand(m.running_mean.shape, generator=g) * 0.2 - 0.1)
                m.running_var.copy_(torch.rand(m.running_var.shape, generator=g) + 0.5)


def compare(a, b) -> dict:
    """Max/mean absolute difference of two equally shaped float tensors."""
    if a.shape != b.shape:
        raise RuntimeError(f"shapes differ: zipon {tuple(a.shape)} vs reference {tuple(b.shape)}")
    d = (a.float() - b.float()).abs_()  # float32: differences near 1e-5 of unit features are exact to ~1e-12
    return {"max_abs_diff": float(d.max()), "mean_abs_diff": float(d.double().mean()), "shape": list(a.shape)}


@contextlib.contextmanager
def on_path(*paths: Path):
    added = [str(p) for p in paths]
    sys.path[:0] = added
    try:
        yield
    finally:
        for p in added:
            sys.path.remove(p)


_CLIP_MODELS: dict[str, object] = {}  # OpenAI CLIP name -> the random model clip.load hands out
_OPENAI_TO_OPEN_CLIP = {"ViT-B/32": "ViT-B-32-quickgelu", "ViT-B/16": "ViT-B-16-quickgelu"}


def install_clip_shim() -> None:
    """A stand-in for OpenAI's ``clip`` package (see the module docstring)."""
    import open_clip

    def load(name, device="cpu", jit=False):
        model = _CLIP_MODELS.get(name)
        if model is None:
            model = open_clip.create_model(_OPENAI_TO_OPEN_CLIP[name], pretrained=None)
        model = model.eval()
        return (model.half() if str(device).startswith("cuda") else model.float()), None

    mod = types.ModuleType("clip")
    mod.load, mod.tokenize = load, open_clip.tokenize
    sys.modules["clip"] = mod


# ----------------------------------------------------------------------------- LSeg

def check_lseg(path: Path, rgb, work: Path, crop: int) -> dict:
    import timm
    import torch

    from pipeline.encoders.lseg import LSegEncoder, load_lseg_net, read_lseg_state_dict
    from pipeline.encoders.lseg_net import LSegNet

    torch.manual_seed(0)
    net = LSegNet()
    perturb(net, 0)
    ckpt = work / "lseg_random.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, ckpt)
    del net
    gc.collect()

    enc = LSegEncoder(load_lseg_net(ckpt), weights=ckpt, crop_size=crop, batch_size=1)
    windows, ours = [], []
    encode = enc.net.encode_image

    def recording(x):
        out = encode(x)
        windows.append(x.clone())
        ours.append(out.clone())
        return out

    enc.net.encode_image = recording
    enc.encode_images(rgb[None])
    del enc
    gc.collect()

    install_clip_shim()
    create = timm.create_model
    timm.create_model = lambda name, pretrained=False, **kw: create(name, pretrained=False, **kw)
    try:
        with on_path(path):
            from modules.models.lseg_net import LSegNet as RefLSegNet

            ref = RefLSegNet(labels=["other"], backbone="clip_vitl16_384", features=256, crop_size=crop,
                             arch_option=0, block_depth=0, activation="lrelu", readout="project")
    finally:
        timm.create_model = create
    ref.load_state_dict(read_lseg_state_dict(ckpt), strict=True)
    ref.eval()
    theirs = []
    hook = ref.scratch.head1.register_forward_hook(lambda m, i, o: theirs.append(o.float()))
    with torch.no_grad():
        for x in windows:
            ref(x, labelset=["other"])
    hook.remove()
    ref_feat = torch.cat([f / f.norm(dim=1, keepdim=True) for f in theirs])  # as LSeg.forward normalises
    result = compare(torch.cat(ours), ref_feat)
    result.update(windows=len(windows), crop=crop, timm=timm.__version__,
                  compared="per-window unit features at the DPT head's resolution (crop/2)")
    return result


# ----------------------------------------------------------------------------- MaskCLIP

def install_mmcv_ext_stub() -> None:
    """mmcv without compiled ops: an ``mmcv._ext`` whose every op raises (none is called on this path)."""
    class _Ext(types.ModuleType):
        def __getattr__(self, name):
            if name.startswith("__"):
                raise AttributeError(name)

            def op(*a, **k):
                raise RuntimeError(f"mmcv op {name} is not built here (MMCV_WITH_OPS=0)")
            return op

    sys.modules.setdefault("mmcv._ext", _Ext("mmcv._ext"))


def check_maskclip(path: Path, rgb, work: Path, arch: str = "ViT-B-16") -> dict:
    import open_clip
    import torch

    from pipeline.encoders.maskclip import MaskClipEncoder, load_open_clip

    torch.manual_seed(1)
    model = open_clip.create_model(arch, pretrained=None)
    perturb(model, 1)
    weights = work / "maskclip_random.pt"
    torch.save(model.state_dict(), weights)
    enc = MaskClipEncoder(load_open_clip(arch, weights, "maskclip.weights"), arch=arch, weights=weights,
                          input_size=tuple(rgb.shape[:2]), batch_size=1)
    x = enc.preprocess(rgb[None])
    ours = enc.encode_images(rgb[None]).features  # (1, gh, gw, D) unit features

    install_clip_shim()
    install_mmcv_ext_stub()
    _CLIP_MODELS["ViT-B/16"] = model
    (work / "pretrain").mkdir(exist_ok=True)
    cwd, argv = os.getcwd(), sys.argv
    try:
        os.chdir(work)
        with on_path(path):
            for extra in ([], ["--backbone"]):  # MaskCLIP's own conversion: head projection, then backbone
                sys.argv = ["convert_clip_weights.py", "--model", "ViT16", *extra]
                runpy.run_path(str(path / "tools" / "maskclip_utils" / "convert_clip_weights.py"), run_name="__main__")
            import mmcv
            from mmcv.runner import load_checkpoint
            from mmseg.models import build_segmentor

            cfg = mmcv.Config.fromfile(str(path / "configs" / "_base_" / "models" / "maskclip_vit16.py"))
            cfg.model.decode_head.update(text_embeddings_path=None,
                                         visual_projs_path=str(work / "pretrain" / "ViT16_clip_weights.pth"))
            cfg.model.decode_head.norm_cfg = dict(type="BN", requires_grad=True)  # SyncBN needs a process group
            load = torch.load
            torch.load = lambda f, map_location=None, **kw: load(f, map_location="cpu", **kw)
            try:
                seg = build_segmentor(cfg.model)
            finally:
                torch.load = load
            ckpt = torch.load(work / "pretrain" / "ViT16_clip_backbone.pth", map_location="cpu")
            missing = {f"backbone.{k}" for k in seg.backbone.state_dict()} - set(ckpt["state_dict"])
            if missing:
                raise RuntimeError(f"MaskCLIP's converted checkpoint lacks {sorted(missing)[:5]}")
            load_checkpoint(seg, str(work / "pretrain" / "ViT16_clip_backbone.pth"), map_location="cpu")
    finally:
        os.chdir(cwd)
        sys.argv = argv
    seg.eval()
    theirs = []
    hook = seg.decode_head.proj.register_forward_hook(lambda m, i, o: theirs.append(o))
    with torch.no_grad():
        seg.decode_head.forward_test(seg.extract_feat(x), [{}], seg.test_cfg)
    hook.remove()
    feat = theirs[0] / theirs[0].norm(dim=1, keepdim=True)  # as MaskClipHead.cls_seg normalises
    result = compare(ours, feat.permute(0, 2, 3, 1))
    result.update(arch=arch, input=list(x.shape[-2:]), mmcv=mmcv.__version__,
                  compared="unit patch features (MaskCLIP head input, before the text classifier)")
    return result


# ----------------------------------------------------------------------------- ConceptFusion

def check_conceptfusion(path: Path, rgb, depth, rgb_file: Path, work: Path, arch: str = "ViT-B-32") -> dict:
    import numpy as np
    import open_clip
    import torch
    from open_clip.model import get_model_preprocess_cfg
    from open_clip.transform import PreprocessCfg, image_transform_v2

    from pipeline.encoder_params.conceptfusion import RegionParams
    from pipeline.encoders.conceptfusion import ConceptFusionEncoder
    from pipeline.encoders.maskclip import load_open_clip
    from pipeline.encoders.regions import Regions, RGBDRegions

    H, W = rgb.shape[:2]
    torch.manual_seed(2)
    model = open_clip.create_model(arch, pretrained=None)
    perturb(model, 2)
    weights = work / "cf_random.pt"
    torch.save(model.state_dict(), weights)
    proposer = RGBDRegions(RegionParams(work_height=H))
    cut = proposer(rgb, depth, None).masks  # disjoint; SAM's overlap (an object and its parts): add the unions of
    # pairs of the largest regions after them, so the overlapping path (in-order renormalisation) is compared too
    unions = cut[: 2 * MERGED : 2] | cut[1 : 2 * MERGED : 2]
    regions = Regions(np.concatenate([cut, unions]), (H, W))

    class Given:  # zipon's encoder gets the same masks, in the same order
        params = proposer.params

        def __call__(self, rgb, depth_m, instance):
            return regions

    enc = ConceptFusionEncoder(load_open_clip(arch, weights, "conceptfusion.weights"), Given(), arch=arch,
                               weights=weights, out_size=(H, W), batch_size=1)
    out = enc.encode_images(rgb[None], depth_m=depth[None])
    ours, valid = out.features[0], out.valid[0]
    del out, enc
    gc.collect()

    # the reference's SAM output: the same masks, in the same order; bbox xywh covering each whole mask
    boxes = regions.boxes_px().round().astype(int)
    sam_masks = [{"segmentation": m, "bbox": [int(b[0]), int(b[1]), int(b[2] - b[0]), int(b[3] - b[1])],
                  "area": int(m.sum())} for m, b in zip(regions.masks, boxes)]
    save_dir = work / "cf_out"  # set per reference run below

    class _Dataset:
        color_paths = [str(rgb_file)]

        def __len__(self):
            return 1

    class _MaskGenerator:
        def __init__(self, model=None, **kw):
            pass

        def generate(self, img):
            return sam_masks

    class _Sam:
        def to(self, device=None):
            return self

    def stub(name: str, **attrs) -> None:
        mod = types.ModuleType(name)
        mod.__dict__.update(attrs)
        sys.modules[name] = mod

    stub("gradslam")
    stub("gradslam.datasets", ICLDataset=lambda *a, **k: _Dataset(), ReplicaDataset=None, ScannetDataset=None,
         load_dataset_config=lambda p: {"dataset_name": "icl"})
    stub("gradslam.slam")
    stub("gradslam.slam.pointfusion", PointFusion=None)
    stub("gradslam.structures")
    stub("gradslam.structures.pointclouds", Pointclouds=None)
    stub("gradslam.structures.rgbdimages", RGBDImages=None)
    stub("segment_anything", SamAutomaticMaskGenerator=_MaskGenerator, SamPredictor=None,
         sam_model_registry={"vit_h": lambda checkpoint=None: _Sam()})
    with contextlib.suppress(ImportError):
        import open3d  # noqa: F401  (imported, unused, by the reference)
    if "open3d" not in sys.modules:
        stub("open3d")

    def program_args(cls):
        return cls(device="cpu", save_dir=str(save_dir), desired_height=H, desired_width=W)

    stub("tyro", cli=program_args)

    def create_model_and_transforms(name, pretrained=None, **kw):  # open_clip's own eval transform, as it builds it
        m = load_open_clip(arch, weights, "conceptfusion.weights")
        return m, None, image_transform_v2(PreprocessCfg(**get_model_preprocess_cfg(m)), is_train=False)

    def run_reference(out_dir: Path, fp32: bool):
        """The reference's ``main()``; ``fp32``: its fp16 casts (``.half()``, ``dtype=torch.half``) kept in fp32."""
        nonlocal save_dir
        save_dir = out_dir
        saved = (open_clip.create_model_and_transforms, torch.Tensor.cuda, torch.nn.Module.cuda, torch.Tensor.half,
                 torch.half)
        open_clip.create_model_and_transforms = create_model_and_transforms
        torch.Tensor.cuda = lambda self, *a, **k: self
        torch.nn.Module.cuda = lambda self, *a, **k: self
        if fp32:
            torch.Tensor.half, torch.half = (lambda self, *a, **k: self.float()), torch.float32
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # torch.cuda.amp.autocast on a CPU-only machine
                runpy.run_path(str(path / "examples" / "extract_conceptfusion_features.py"))["main"]()
        finally:
            (open_clip.create_model_and_transforms, torch.Tensor.cuda, torch.nn.Module.cuda, torch.Tensor.half,
             torch.half) = saved
        return torch.load(out_dir / (rgb_file.stem + ".pt"), map_location="cpu")  # (H, W, D)

    results = []
    for fp32 in (False, True):
        theirs = run_reference(work / ("cf_fp32" if fp32 else "cf_out"), fp32)
        result = compare(ours, theirs)
        result.update(arch=arch, regions=len(regions), overlapping=MERGED,
                      same_valid_cells=bool(torch.equal(valid, theirs.float().norm(dim=-1) > 0)),
                      reference_dtype=str(theirs.dtype),
                      compared="fused unit features per pixel at the frame's size (cells in no region: 0 in both)")
        if not fp32:  # the features as the reference stores them: fp16, one spacing at the peak is its resolution
            peak = float(theirs.float().abs().max())
            result["fp16_spacing_at_peak"] = float(2.0 ** (np.floor(np.log2(peak)) - 10))
        else:
            result["variant"] = "the reference's fp16 casts kept in fp32 (its fusion rule at zipon's precision)"
        results.append(result)
        del theirs
        gc.collect()
    return results


# ----------------------------------------------------------------------------- main

def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_args(argv)
        if args.refdeps is not None:
            sys.path.insert(0, str(args.refdeps))
        if str(ROOT) not in sys.path:
            sys.path.insert(0, str(ROOT))
        rgb, depth, rgb_file = load_frame(args.frames, args.frame_index)
    except UsageError as err:
        print(f"check_reference.py: error: {err}", file=sys.stderr)
        return 2
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    worst = 0
    with tempfile.TemporaryDirectory(prefix="zipon-check-") as tmp:
        for name in args.chosen:
            path: Path = getattr(args, name).resolve()
            work = Path(tmp) / name
            work.mkdir()
            t0 = time.perf_counter()
            if name == "lseg":
                results = [("lseg", check_lseg(path, rgb, work, args.lseg_crop))]
            elif name == "maskclip":
                results = [("maskclip", check_maskclip(path, rgb, work))]
            else:
                as_stored, fp32 = check_conceptfusion(path, rgb, depth, rgb_file, work)
                results = [("conceptfusion", as_stored), ("conceptfusion_fp32", fp32)]
            seconds = round(time.perf_counter() - t0, 1)
            for label, res in results:
                # the reference rounds each cell's feature to fp16 three times (add, renormalise, final renormalise),
                # each by up to half a spacing: it can agree no closer than 1.5 fp16 spacings at the peak value
                tol = max(args.tol, FP16_ROUNDINGS * 0.5 * res.get("fp16_spacing_at_peak", 0.0))
                ok = res["max_abs_diff"] <= tol
                worst |= not ok
                print(json.dumps({"encoder": label, "reference": REFERENCES[name][0], "commit": commit_of(path),
                                  "frame": str(rgb_file.relative_to(args.frames.parent)), "tol": tol, "ok": ok,
                                  **res, "seconds": seconds}), flush=True)
            gc.collect()
    return 1 if worst else 0


if __name__ == "__main__":
    sys.exit(main())
