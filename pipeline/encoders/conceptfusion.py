"""``conceptfusion``: the ConceptFusion pixel features (Jatavallabhula et al., RSS 2023).

As the reference code does (concept-fusion ``examples/extract_conceptfusion_features.py``), per frame:
the global CLIP feature ``g`` of the whole image and the local CLIP feature ``l_i`` of each region's
bounding-box crop, every image going through the model's own open_clip eval transform (shorter side
resized bicubically to the input size, centre crop, CLIP normalisation: :func:`eval_transform`); the
crops of all regions of all frames of a batch are encoded ``CROPS_PER_PASS`` at a time, never one call
per region. ``w_i = softmax_i(cos(g, l_i) / T)`` over the frame's regions;
``f_i = normalise(w_i g + (1 - w_i) l_i)``; region by region, in order, ``f_i`` is added to the
region's cells and those cells renormalised (so where SAM's masks overlap, later regions weigh more,
as in the reference). Cells in no region are marked invalid (``valid`` False, feature 0), never filled
with a made-up feature. Differences from the reference, by design: features stay float32 (it stores
fp16), and a cell of the ``out_size`` grid reads the region masks at its centre (its final 'nearest'
resize reads each cell's top-left pixel). ``benchmarks/check_reference.py --conceptfusion`` runs the
reference's own code against this one.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn as nn
from open_clip.model import get_model_preprocess_cfg
from open_clip.transform import PreprocessCfg, image_transform_v2
from PIL import Image

from pipeline.encoder_params.conceptfusion import ConceptFusionParams, RegionParams
from pipeline.encoders.base import DenseFeatures, Encoder, OpenClipText, l2_normalize, require_file
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


def eval_transform(model: nn.Module):
    """The model's own open_clip eval transform (PIL image -> normalised tensor), as ``create_model_and_transforms``
    builds it: shorter side resized (bicubic, antialiased) to the input size, centre crop, CLIP mean/std."""
    return image_transform_v2(PreprocessCfg(**get_model_preprocess_cfg(model)), is_train=False)


def pixel_boxes(regions: Regions) -> np.ndarray:
    """``(R,4)`` int ``x0, y0, x1, y1`` (end exclusive) pixel boxes covering each region's mask cells."""
    H, W = regions.image_size
    b = regions.boxes_px()
    lo, hi = np.floor(b[:, :2] + 1e-4), np.ceil(b[:, 2:] - 1e-4)
    return np.concatenate([lo, np.minimum(hi, [W, H])], axis=1).astype(np.int64)


def paint_regions(fused: torch.Tensor, masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Region features onto cells as ConceptFusion does: ``(R,D)`` unit features, ``(R,N)`` bool masks ->
    ``(N,D)`` features, ``(N,)`` valid. Region by region, in order, the feature is added to the region's cells and
    those cells renormalised; cells in no region stay 0."""
    out = fused.new_zeros(masks.shape[1], fused.shape[1])
    valid = masks.any(dim=0)
    if masks.shape[0] == 0:
        return out, valid
    if int(masks.sum(dim=0).max()) <= 1:  # disjoint regions: each covered cell takes its region's feature
        out[valid] = fused[masks.float().argmax(dim=0)[valid]]
        return out, valid
    for i in range(masks.shape[0]):  # overlapping regions (SAM): order matters, as in the reference
        cells = masks[i].nonzero().squeeze(1)
        out[cells] = l2_normalize(out[cells] + fused[i])
    return out, valid


class ConceptFusionEncoder(OpenClipText, Encoder):
    """ConceptFusion global+local CLIP features on regions; see the module docstring."""

    name = "conceptfusion"
    params_model = ConceptFusionParams
    version = "2"  # 2: the reference's crop transform (resize + centre crop) and its in-order renormalisation

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
        self._transform = eval_transform(model)
        self.softmax_temperature = float(softmax_temperature)
        self.out_size = tuple(out_size)
        self._tokenize = clip_tokens(arch)

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "ConceptFusionEncoder":
        p = cls.settings(params)
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
        """``(N,3,S,S)`` normalised crops -> ``(N,D)`` image features, ``CROPS_PER_PASS`` at a time."""
        out = [self.model.encode_image(crops[i : i + CROPS_PER_PASS].to(self.device)).float()
               for i in range(0, crops.shape[0], CROPS_PER_PASS)]
        return torch.cat(out) if out else crops.new_zeros((0, self.dim))

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        B, H, W, _ = rgb.shape
        regions: list[Regions] = [
            self.regions(rgb[b], None if depth_m is None else depth_m[b], None if instance is None else instance[b])
            for b in range(B)
        ]
        crops = []  # per frame: the whole image, then each region's box (PIL crops, as the reference cuts them)
        for b, r in enumerate(regions):
            image = Image.fromarray(np.ascontiguousarray(rgb[b]))
            crops.append(self._transform(image))
            crops.extend(self._transform(image.crop(tuple(int(v) for v in box))) for box in pixel_boxes(r))
        feats = self._clip(torch.stack(crops))
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
            out[b], valid[b] = paint_regions(fused[start : start + len(r)], masks)
            start += len(r)
        return DenseFeatures(out.reshape(B, h, w, -1).cpu(), valid.reshape(B, h, w).cpu(), (H, W))
