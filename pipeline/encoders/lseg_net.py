"""The LSeg network (Li et al., ICLR 2022), written natively for inference.

A DPT decoder on a ViT-L/16 image backbone, with the CLIP ViT-B/32 model as text encoder. Module
and parameter names follow the public implementation (isl-org/lang-seg ``modules/models/lseg_net.py``,
``lseg_blocks.py``, ``lseg_vit.py``; timm 0.4.12 ``vit_large_patch16_384``; OpenAI CLIP) so that
the public checkpoint's ``state_dict`` (keys prefixed ``net.``) loads with strict matching:

- ``clip_pretrained.*``   the whole CLIP ViT-B/32 (only its text tower runs here)
- ``pretrained.model.*``  the ViT: ``cls_token``, ``pos_embed``, ``patch_embed.proj``, ``blocks.i``
  (``norm1``, ``attn.qkv``, ``attn.proj``, ``norm2``, ``mlp.fc1``, ``mlp.fc2``), ``norm``, ``head``
- ``pretrained.act_postprocess{1..4}``  readout projection (index 0), 1x1 conv (3), resampling (4)
- ``scratch.layer{1..4}_rn``, ``scratch.refinenet{1..4}`` (batch-normed residual fusion blocks),
  ``scratch.head1`` (1x1 conv to the 512-d CLIP space)

Only ``arch_option=0`` (no extra head block) is implemented: the demo checkpoint and VLMaps use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import open_clip
import torch
import torch.nn as nn
import torch.nn.functional as F
from open_clip.model import CLIP, CLIPTextCfg, CLIPVisionCfg


@dataclass(frozen=True)
class LSegArch:
    """Sizes of an LSeg network; :data:`LSEG_VITL16_384` is the public one."""

    vit_width: int = 1024
    vit_depth: int = 24
    vit_heads: int = 16
    patch_size: int = 16
    pos_grid: int = 24  # 384 / 16: position embeddings are learnt on a 24x24 grid and resized
    num_classes: int = 1000  # timm's (unused) classifier head, present in the checkpoint
    hooks: tuple[int, int, int, int] = (5, 11, 17, 23)
    post_channels: tuple[int, int, int, int] = (256, 512, 1024, 1024)
    features: int = 256
    embed_dim: int = 512  # CLIP joint space = LSeg's out_c
    clip_vision: dict = field(default_factory=lambda: {"layers": 12, "width": 768, "patch_size": 32, "image_size": 224})
    clip_text: dict = field(default_factory=lambda: {"context_length": 77, "vocab_size": 49408, "width": 512,
                                                      "heads": 8, "layers": 12})
    name: str = "clip_vitl16_384"


LSEG_VITL16_384 = LSegArch()


def tiny_arch() -> LSegArch:
    """A reduced network with the same layout (tests, speed checks); no public weights exist for it."""
    return LSegArch(
        vit_width=32, vit_depth=4, vit_heads=2, pos_grid=4, hooks=(0, 1, 2, 3), post_channels=(8, 16, 32, 32),
        features=16, embed_dim=32, num_classes=10,
        clip_vision={"layers": 1, "width": 32, "head_width": 16, "patch_size": 32, "image_size": 64},
        clip_text={"context_length": 77, "vocab_size": 49408, "width": 32, "heads": 2, "layers": 1},
        name="tiny",
    )


# ----------------------------------------------------------------------------- ViT (timm names)

class _Attention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, dim * 3)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, N, C = x.shape
        q, k, v = self.qkv(x).reshape(B, N, 3, self.heads, C // self.heads).permute(2, 0, 3, 1, 4)
        x = F.scaled_dot_product_attention(q, k, v)
        return self.proj(x.transpose(1, 2).reshape(B, N, C))


class _Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class _Block(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = _Attention(dim, heads)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = _Mlp(dim, dim * 4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class _PatchEmbed(nn.Module):
    def __init__(self, dim: int, patch: int):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, kernel_size=patch, stride=patch)


class _VisionTransformer(nn.Module):
    def __init__(self, a: LSegArch):
        super().__init__()
        self.patch_size = a.patch_size
        self.cls_token = nn.Parameter(torch.zeros(1, 1, a.vit_width))
        self.pos_embed = nn.Parameter(torch.randn(1, a.pos_grid**2 + 1, a.vit_width) * 0.02)
        self.patch_embed = _PatchEmbed(a.vit_width, a.patch_size)
        self.blocks = nn.ModuleList(_Block(a.vit_width, a.vit_heads) for _ in range(a.vit_depth))
        self.norm = nn.LayerNorm(a.vit_width, eps=1e-6)
        self.head = nn.Linear(a.vit_width, a.num_classes)  # unused; in the checkpoint

    def hooked_tokens(self, x: torch.Tensor, hooks: tuple[int, ...]) -> list[torch.Tensor]:
        """Token sequences ``(B,1+gh*gw,C)`` after the blocks in ``hooks`` (later blocks are skipped)."""
        gh, gw = x.shape[2] // self.patch_size, x.shape[3] // self.patch_size
        tok, grid = self.pos_embed[:, :1], self.pos_embed[0, 1:]
        g0 = int(round(grid.shape[0] ** 0.5))
        grid = grid.reshape(1, g0, g0, -1).permute(0, 3, 1, 2)
        grid = F.interpolate(grid, size=(gh, gw), mode="bilinear", align_corners=False)
        pos = torch.cat([tok, grid.permute(0, 2, 3, 1).reshape(1, gh * gw, -1)], dim=1)
        x = self.patch_embed.proj(x).flatten(2).transpose(1, 2)
        x = torch.cat([self.cls_token.expand(x.shape[0], -1, -1), x], dim=1) + pos
        out = []
        for i, blk in enumerate(self.blocks[: max(hooks) + 1]):
            x = blk(x)
            if i in hooks:
                out.append(x)
        return out


class _ProjectReadout(nn.Module):
    """Concatenate each patch token with the class token and project back (DPT 'project' readout)."""

    def __init__(self, dim: int):
        super().__init__()
        self.project = nn.Sequential(nn.Linear(2 * dim, dim), nn.GELU())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        patches = x[:, 1:]
        return self.project(torch.cat([patches, x[:, :1].expand_as(patches)], dim=-1))


def _postprocess(dim: int, out: int, resample: nn.Module | None) -> nn.Sequential:
    # indices 1 and 2 (transpose, unflatten) hold no parameters; kept so indices 3/4 match the checkpoint
    mods = [_ProjectReadout(dim), nn.Identity(), nn.Identity(), nn.Conv2d(dim, out, kernel_size=1)]
    return nn.Sequential(*mods, *([resample] if resample is not None else []))


# ----------------------------------------------------------------------------- DPT decoder

class _ResidualConvUnit(nn.Module):
    def __init__(self, features: int):
        super().__init__()
        self.conv1 = nn.Conv2d(features, features, 3, padding=1, bias=False)
        self.conv2 = nn.Conv2d(features, features, 3, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(features)
        self.bn2 = nn.BatchNorm2d(features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.bn1(self.conv1(F.relu(x)))
        out = self.bn2(self.conv2(F.relu(out)))
        return out + x


class _FusionBlock(nn.Module):
    def __init__(self, features: int):
        super().__init__()
        self.out_conv = nn.Conv2d(features, features, kernel_size=1)
        self.resConfUnit1 = _ResidualConvUnit(features)
        self.resConfUnit2 = _ResidualConvUnit(features)

    def forward(self, x: torch.Tensor, skip: torch.Tensor | None = None) -> torch.Tensor:
        if skip is not None:
            x = x + self.resConfUnit1(skip)
        x = self.resConfUnit2(x)
        x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=True)
        return self.out_conv(x)


class LSegNet(nn.Module):
    """LSeg with the public checkpoint's parameter layout; see the module docstring."""

    def __init__(self, arch: LSegArch = LSEG_VITL16_384):
        super().__init__()
        a = self.arch = arch
        if a.patch_size != 16:
            raise ValueError("only the /16 backbone layout (clip_vitl16_384) is implemented")
        self.clip_pretrained = CLIP(
            a.embed_dim, CLIPVisionCfg(**a.clip_vision), CLIPTextCfg(**a.clip_text), quick_gelu=True
        )
        d, c = a.vit_width, a.post_channels
        self.pretrained = nn.Module()
        self.pretrained.model = _VisionTransformer(a)
        self.pretrained.act_postprocess1 = _postprocess(d, c[0], nn.ConvTranspose2d(c[0], c[0], 4, stride=4))
        self.pretrained.act_postprocess2 = _postprocess(d, c[1], nn.ConvTranspose2d(c[1], c[1], 2, stride=2))
        self.pretrained.act_postprocess3 = _postprocess(d, c[2], None)
        self.pretrained.act_postprocess4 = _postprocess(d, c[3], nn.Conv2d(c[3], c[3], 3, stride=2, padding=1))
        self.scratch = nn.Module()
        for i in range(4):
            setattr(self.scratch, f"layer{i + 1}_rn", nn.Conv2d(c[i], a.features, 3, padding=1, bias=False))
        for i in range(4):
            setattr(self.scratch, f"refinenet{i + 1}", _FusionBlock(a.features))
        self.scratch.head1 = nn.Conv2d(a.features, a.embed_dim, kernel_size=1)

    @property
    def temperature(self) -> float:
        return 0.07  # LSeg's fixed logit scale is 1 / 0.07

    def encode_image(self, x: torch.Tensor) -> torch.Tensor:
        """``(B,3,S,S)`` normalised crops (S a multiple of 32) -> ``(B,512,S/2,S/2)`` unit-norm pixel features.

        LSeg then upsamples x2 bilinearly (align_corners); callers do that resampling themselves.
        """
        gh, gw = x.shape[2] // 16, x.shape[3] // 16
        toks = self.pretrained.model.hooked_tokens(x, self.arch.hooks)
        layers = []
        for i, t in enumerate(toks):
            post = getattr(self.pretrained, f"act_postprocess{i + 1}")
            y = post[0](t).transpose(1, 2).reshape(t.shape[0], -1, gh, gw)
            for m in post[3:]:
                y = m(y)
            layers.append(getattr(self.scratch, f"layer{i + 1}_rn")(y))
        path = self.scratch.refinenet4(layers[3])
        path = self.scratch.refinenet3(path, layers[2])
        path = self.scratch.refinenet2(path, layers[1])
        path = self.scratch.refinenet1(path, layers[0])
        feat = self.scratch.head1(path)
        return feat / feat.norm(dim=1, keepdim=True).clamp_min(1e-12)

    def encode_text(self, tokens: torch.Tensor) -> torch.Tensor:
        """``(T,77)`` CLIP tokens -> ``(T,512)`` unit-norm text features."""
        f = self.clip_pretrained.encode_text(tokens)
        return f / f.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def tokenizer():
    """CLIP's BPE tokenizer (ships inside open_clip; nothing is downloaded)."""
    return open_clip.get_tokenizer("ViT-B-32")
