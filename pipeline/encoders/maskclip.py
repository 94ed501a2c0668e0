"""``maskclip``: dense CLIP-space features from any open_clip ViT, MaskCLIP-style (Zhou et al., ECCV 2022).

The image runs through the ViT at ``input_size`` (position embeddings resized bicubically to the
patch grid); in the last block the query-key attention is dropped and each token keeps only its own
value path, exactly as MaskCLIP's code does (chongzhou/MaskCLIP, mmseg ``VisionTransformer`` with
``return_qkv``): ``v = x + out_proj(W_v ln_1(x) + b_v)``, then the block's MLP with its residual,
``v = v + mlp(ln_2(v))``, then ``ln_post`` and ``proj`` per patch token. That is the last block run
with every token attending only to itself. Each patch token becomes one feature cell: the grid is
``input_size / patch`` (ViT-B-32 at 480x640: 15x20), optionally resampled to ``out_size``.
Text features are the model's own ``encode_text``: the same joint space (512-d for ViT-B-32).
``benchmarks/check_reference.py --maskclip`` compares these features with MaskCLIP's own code.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import open_clip
import torch
import torch.nn as nn
import torch.nn.functional as F

from pipeline.encoder_params.maskclip import MaskClipParams
from pipeline.encoders.base import (
    CLIP_MEAN,
    CLIP_STD,
    DenseFeatures,
    Encoder,
    OpenClipText,
    all_valid,
    normalize,
    require_file,
    resize_features,
    to_tensor01,
    weights_error,
)
from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from pipeline.config import EncodersParams


def load_open_clip(arch: str, path: Path, param: str) -> nn.Module:
    """An open_clip model ``arch`` with weights from a local file (strict); errors name ``param`` and the file."""
    if arch not in open_clip.list_models():
        raise ConfigError(f"{param.rsplit('.', 1)[0]}.arch: unknown open_clip model {arch!r}")
    model = open_clip.create_model(arch, pretrained=None)
    try:
        open_clip.load_checkpoint(model, str(path), strict=True)
    except Exception as err:  # noqa: BLE001 - any load failure is reported as unusable weights
        raise weights_error(param, path, err) from None
    return model.eval()


def clip_tokens(arch: str):
    """The tokenizer of ``arch`` (CLIP BPE ships inside open_clip)."""
    return open_clip.get_tokenizer(arch)


def check_plain_vit(visual: nn.Module, param: str) -> None:
    """MaskCLIP needs a plain open_clip ViT (class token, nn.MultiheadAttention blocks, no attention pooling)."""
    ok = isinstance(visual, open_clip.transformer.VisionTransformer) and visual.attn_pool is None
    ok = ok and all(isinstance(b.attn, nn.MultiheadAttention) for b in visual.transformer.resblocks)
    if not ok:
        raise ConfigError(f"{param}: MaskCLIP needs a plain open_clip ViT image tower (got {type(visual).__name__})")


def vit_tokens(visual: nn.Module, x: torch.Tensor, upto: int) -> torch.Tensor:
    """Tokens ``(B,1+gh*gw,C)`` entering block ``upto`` of an open_clip ViT, for any input size."""
    pw, ph = visual.conv1.kernel_size[1], visual.conv1.kernel_size[0]
    gh, gw = x.shape[2] // ph, x.shape[3] // pw
    x = visual.conv1(x).flatten(2).transpose(1, 2)
    pos = visual.positional_embedding
    g0h, g0w = visual.grid_size
    if (gh, gw) != (g0h, g0w):
        grid = pos[1:].reshape(1, g0h, g0w, -1).permute(0, 3, 1, 2)
        grid = F.interpolate(grid, size=(gh, gw), mode="bicubic", align_corners=False)
        pos = torch.cat([pos[:1], grid.permute(0, 2, 3, 1).reshape(gh * gw, -1)])
    cls = visual.class_embedding.to(x.dtype).expand(x.shape[0], 1, -1)
    x = visual.ln_pre(torch.cat([cls, x], dim=1) + pos.to(x.dtype))
    batch_first = getattr(visual.transformer, "batch_first", True)
    if not batch_first:
        x = x.transpose(0, 1)
    for blk in visual.transformer.resblocks[:upto]:
        x = blk(x)
    return x if batch_first else x.transpose(0, 1)


def maskclip_patch_features(visual: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``(B,3,H,W)`` CLIP-normalised images -> ``(B,D,gh,gw)`` unnormalised joint-space patch features."""
    gh, gw = x.shape[2] // visual.conv1.kernel_size[0], x.shape[3] // visual.conv1.kernel_size[1]
    last = visual.transformer.resblocks[-1]
    tokens = vit_tokens(visual, x, len(visual.transformer.resblocks) - 1)
    tokens = tokens[:, 1:]  # every step below is per token: the class token is not needed
    C = tokens.shape[-1]
    attn: nn.MultiheadAttention = last.attn
    v = F.linear(last.ln_1(tokens), attn.in_proj_weight[2 * C :], attn.in_proj_bias[2 * C :])
    v = tokens + last.ls_1(attn.out_proj(v))  # the value path with the block's residual (MaskCLIP: v += x)
    v = visual.ln_post(v + last.ls_2(last.mlp(last.ln_2(v))))  # and its MLP with residual, as MaskCLIP keeps
    if visual.proj is not None:
        v = v @ visual.proj
    return v.transpose(1, 2).reshape(x.shape[0], -1, gh, gw)


class MaskClipEncoder(OpenClipText, Encoder):
    """MaskCLIP dense features of an open_clip ViT; see the module docstring."""

    name = "maskclip"
    params_model = MaskClipParams
    version = "2"  # 2: the last block keeps its residual and MLP, as MaskCLIP's code does

    def __init__(
        self,
        model: nn.Module,
        *,
        arch: str,
        weights: Path | None,
        input_size: tuple[int, int] = (480, 640),
        out_size: tuple[int, int] | None = None,
        device: str = "cpu",
        batch_size: int = 4,
    ):
        super().__init__(device=device, batch_size=batch_size)
        check_plain_vit(model.visual, "encoders.maskclip.arch")
        self.model = model.to(self.device).eval()
        self.arch, self.weights = arch, weights
        patch = model.visual.conv1.kernel_size
        if input_size[0] % patch[0] or input_size[1] % patch[1]:
            raise ConfigError(f"encoders.maskclip.input_size {tuple(input_size)} must be multiples of the patch {patch}")
        self.input_size = tuple(input_size)
        self.out_size = tuple(out_size) if out_size is not None else None
        self._tokenize = clip_tokens(arch)

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "MaskClipEncoder":
        p = cls.settings(params)
        param = "encoders.maskclip.weights"
        path = require_file(p.weights, param, f"the maskclip encoder (open_clip {p.arch} weights)")
        return cls(load_open_clip(p.arch, path, param), arch=p.arch, weights=path, input_size=p.input_size,
                   out_size=p.out_size, device=device, batch_size=batch_size)

    @property
    def dim(self) -> int:
        return int(self.model.visual.output_dim)

    def config_identity(self) -> dict[str, Any]:
        return {"arch": self.arch, "input_size": list(self.input_size),
                "out_size": list(self.out_size) if self.out_size else None}

    def preprocess(self, rgb: np.ndarray) -> torch.Tensor:
        """``(B,H,W,3)`` uint8 -> ``(B,3,*input_size)`` CLIP-normalised tensor on the device."""
        x = to_tensor01(rgb, self.device)
        if tuple(x.shape[-2:]) != self.input_size:
            x = F.interpolate(x, size=self.input_size, mode="bilinear", align_corners=False, antialias=True)
        return normalize(x, CLIP_MEAN, CLIP_STD)

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        feat = maskclip_patch_features(self.model.visual, self.preprocess(rgb))
        out = resize_features(feat, self.out_size)
        return DenseFeatures(out, all_valid(out), tuple(rgb.shape[1:3]))
