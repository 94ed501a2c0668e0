"""``conceptfusion``: the ConceptFusion pixel features (Jatavallabhula et al., RSS 2023).

Per frame: the global CLIP feature ``g`` of the whole image and the local CLIP feature ``l_i``
of each region's bounding-box crop (both squashed to the model's input size; the crops of all
regions of all frames of a batch are cut together by :func:`cut_crops` and encoded in batches of
``CROPS_PER_PASS``, never one call per region);
``w_i = softmax_i(cos(g, l_i) / T)`` over the frame's regions; ``f_i = normalise(w_i g + (1 - w_i) l_i)``
is added to the region's cells and each cell renormalised. Cells in no region are marked
invalid (``valid`` False, feature 0), never filled with a made-up feature.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from torchvision.ops import roi_align

from pipeline.config import RegionParams
from pipeline.encoders.base import (
    CLIP_MEAN,
    CLIP_STD,
    DenseFeatures,
    Encoder,
    OpenClipText,
    l2_normalize,
    normalize,
    register,
    require_file,
    to_tensor01,
)
from pipeline.encoders.maskclip import clip_tokens, load_open_clip
from pipeline.encoders.regions import RegionGenerator, Regions, build_region_generator

if TYPE_CHECKING:
    from pipeline.config import EncodersParams

CROPS_PER_PASS = 64


def fuse_region_features(
    g: torch.Tensor, local: torch.Tensor, frame_of: torch.Tensor, n_frames: int, temperature: float = 1.0
) -> torch.Tensor:
    """ConceptFusion's fusion, vectorised over all regions of all frames.

    ``g`` ``(B,D)`` global features, ``local`` ``(R,D)`` region features, ``frame_of`` ``(R,)`` frame
    index of each region. Returns ``(R,D)`` unit-norm fused features.
    """
    g, local = l2_normalize(g), l2_normalize(local)
    gi = g[frame_of]
    sim = (gi * local).sum(-1) / temperature
    # softmax over each frame's regions (segment-wise, stable)
    m = torch.full((n_frames,), -torch.inf, dtype=sim.dtype, device=sim.device).scatter_reduce(
        0, frame_of, sim, reduce="amax")
    e = torch.exp(sim - m[frame_of])
    denom = torch.zeros(n_frames, dtype=sim.dtype, device=sim.device).index_add_(0, frame_of, e)
    w = (e / denom[frame_of]).unsqueeze(-1)
    return l2_normalize(w * gi + (1.0 - w) * local)


def cut_crops(x: torch.Tensor, boxes: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
    """Crop-and-resize every box of every frame: ``(B,3,H,W)`` + per-frame ``(R_b,4)`` pixel boxes -> ``(sum R_b,3,*size)``.

    One bilinear sample per output pixel (``roi_align``, batched over all boxes); boxes more than
    twice the output size are cut from a half-resolution antialiased copy so nothing aliases.
    """
    flat = torch.cat([torch.cat([torch.full((len(bx), 1), float(b)), bx], dim=1) for b, bx in enumerate(boxes)])
    flat = flat.to(x.device)
    big = ((flat[:, 3] - flat[:, 1]) > 2 * size[1]) | ((flat[:, 4] - flat[:, 2]) > 2 * size[0])
    out = torch.empty(len(flat), 3, *size, device=x.device)
    if (~big).any():
        out[~big] = roi_align(x, flat[~big], output_size=size, spatial_scale=1.0, sampling_ratio=1, aligned=True)
    if big.any():
        half = F.interpolate(x, scale_factor=0.5, mode="bilinear", antialias=True, recompute_scale_factor=False)
        out[big] = roi_align(half, flat[big], output_size=size, spatial_scale=0.5, sampling_ratio=1, aligned=True)
    return out


@register
class ConceptFusionEncoder(OpenClipText, Encoder):
    """ConceptFusion global+local CLIP features on regions; see the module docstring."""

    name = "conceptfusion"
    version = "1"

    def __init__(
        self,
        model: nn.Module,
        regions: RegionGenerator,
        *,
        arch: str,
        weights: Path | None,
        softmax_temperature: float = 1.0,
        out_size: tuple[int, int] = (120, 160),
        device: str = "cpu",
        batch_size: int = 4,
    ):
        super().__init__(device=device, batch_size=batch_size)
        self.model = model.to(self.device).eval()
        self.regions = regions
        self.arch, self.weights = arch, weights
        size = model.visual.image_size  # crops go in at the model's own input size (224 for ViT-B-32)
        self.crop_size = tuple(size) if isinstance(size, (tuple, list)) else (int(size), int(size))
        self.softmax_temperature = float(softmax_temperature)
        self.out_size = tuple(out_size)
        self._tokenize = clip_tokens(arch)

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "ConceptFusionEncoder":
        p = params.conceptfusion
        param = "encoders.conceptfusion.weights"
        path = require_file(p.weights, param, f"the conceptfusion encoder (open_clip {p.arch} weights)")
        return cls(load_open_clip(p.arch, path, param), build_region_generator(p.regions), arch=p.arch,
                   weights=path, softmax_temperature=p.softmax_temperature,
                   out_size=p.out_size, device=device, batch_size=batch_size)

    @property
    def dim(self) -> int:
        return int(self.model.visual.output_dim)

    def config_identity(self) -> dict[str, Any]:
        rp: RegionParams = self.regions.params
        return {"arch": self.arch, "crop_size": list(self.crop_size), "softmax_temperature": self.softmax_temperature,
                "out_size": list(self.out_size), "regions": rp.model_dump(mode="json")}

    def _clip(self, crops: torch.Tensor) -> torch.Tensor:
        """``(N,3,S,S)`` [0,1] crops -> ``(N,D)`` image features, ``CROPS_PER_PASS`` at a time."""
        out = [self.model.encode_image(normalize(crops[i : i + CROPS_PER_PASS], CLIP_MEAN, CLIP_STD)).float()
               for i in range(0, crops.shape[0], CROPS_PER_PASS)]
        return torch.cat(out) if out else crops.new_zeros((0, self.dim))

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        B, H, W, _ = rgb.shape
        regions: list[Regions] = [
            self.regions(rgb[b], None if depth_m is None else depth_m[b], None if instance is None else instance[b])
            for b in range(B)
        ]
        whole = torch.tensor([[0.0, 0.0, W, H]], dtype=torch.float32).repeat(B, 1)
        boxes = [torch.cat([whole[b : b + 1], torch.from_numpy(r.boxes_px())]) for b, r in enumerate(regions)]
        feats = self._clip(cut_crops(to_tensor01(rgb, self.device), boxes, self.crop_size))
        counts = [len(r) + 1 for r in regions]
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        is_global = torch.zeros(feats.shape[0], dtype=torch.bool, device=feats.device)
        is_global[torch.as_tensor(first, device=feats.device)] = True
        frame_of = torch.repeat_interleave(torch.arange(B, device=feats.device),
                                           torch.as_tensor(counts, device=feats.device))
        fused = fuse_region_features(feats[is_global], feats[~is_global], frame_of[~is_global], B,
                                     self.softmax_temperature)
        h, w = self.out_size
        out = torch.empty(B, h * w, fused.shape[1], device=fused.device)
        valid = torch.empty(B, h * w, dtype=torch.bool, device=fused.device)
        start = 0
        for b, r in enumerate(regions):
            masks = torch.from_numpy(r.resampled(self.out_size).reshape(len(r), h * w)).to(fused.device)
            f = fused[start : start + len(r)]
            start += len(r)
            valid[b] = masks.any(dim=0)
            if len(r) == 0 or masks.sum(dim=0).max() <= 1:  # disjoint regions: each cell takes its region's feature
                table = torch.cat([f.new_zeros(1, f.shape[1]), f])
                torch.index_select(table, 0, torch.where(valid[b], masks.float().argmax(dim=0) + 1, 0), out=out[b])
                continue
            # overlapping regions (SAM): sum of the covering regions' features, renormalised; uncovered cells stay 0
            torch.mm(masks.T.to(f.dtype), f, out=out[b])
            out[b] /= out[b].norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return DenseFeatures(out.reshape(B, h, w, -1).cpu(), valid.reshape(B, h, w).cpu(), (H, W))
