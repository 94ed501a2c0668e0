"""``lseg``: LSeg pixel features with VLMaps' sliding-window inference.

Per image (as VLMaps ``get_lseg_feat``): normalise with mean = std = 0.5, resize (bilinear,
align_corners) so the long side is ``base_size`` (480x640 -> 390x520), pad with black to at least
``crop_size``, run ``crop_size`` windows with stride ``int(crop_size * stride_rate)`` (each window
padded with black), average the overlapping unit-norm features, keep the image part. The
windows of all images of a batch run through the network together, ``batch_size`` windows per
forward pass. Stitching happens at the head's native half resolution (LSeg's final x2 upsampling
is bilinear, so it commutes with the averaging); the result is resampled to ``out_size`` cells
covering the whole image and renormalised (when the resized height or width is odd, the last
half-resolution cell reaches one resized pixel past the image: under 0.3% of the extent). Features are L2-normalised; LSeg was trained with
logits = cosine / 0.07 (VLMaps stores the features multiplied by 1/0.07): ``temperature`` = 0.07.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F

from pipeline.encoder_params.lseg import LSegParams
from pipeline.encoders.base import (
    DenseFeatures,
    Encoder,
    all_valid,
    normalize,
    require_file,
    resize_features,
    to_tensor01,
    weights_error,
)
from pipeline.encoders.lseg_net import LSEG_VITL16_384, LSegArch, LSegNet, tokenizer

if TYPE_CHECKING:
    from pipeline.config import EncodersParams

WEIGHTS_PARAM = "encoders.lseg.weights"


def read_lseg_state_dict(path: Path, param: str = WEIGHTS_PARAM) -> dict[str, torch.Tensor]:
    """The network's state dict from a lightning checkpoint (``state_dict``, keys ``net.*``) or a bare one.

    Keys outside ``net.`` in a lightning checkpoint (none in the public one) are not the network's
    and are left out. The checkpoint is a pickle: load only files you trust.
    """
    try:
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        except (pickle.UnpicklingError, RuntimeError):
            # lightning checkpoints may pickle hyper-parameters (argparse objects: refused by weights_only), and
            # files in torch's legacy (non-zip) format cannot be memory-mapped (RuntimeError)
            ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001 - any load failure is reported as unusable weights
        raise weights_error(param, path, err) from None
    sd = ckpt.get("state_dict", ckpt) if isinstance(ckpt, dict) else None
    if not isinstance(sd, dict) or not sd:
        raise weights_error(param, path, ValueError("no state_dict in the file"))
    if any(k.startswith("net.") for k in sd):
        sd = {k[len("net."):]: v for k, v in sd.items() if k.startswith("net.")}
    return sd


def load_lseg_net(path: Path, arch: LSegArch = LSEG_VITL16_384, param: str = WEIGHTS_PARAM) -> LSegNet:
    """Build :class:`LSegNet` and load ``path`` with strict key/shape matching (no random init pass)."""
    sd = read_lseg_state_dict(path, param)
    sd = {k: (v.float() if v.is_floating_point() else v) for k, v in sd.items()}  # CLIP parts may be fp16
    with torch.device("meta"):
        net = LSegNet(arch)
    try:
        net.load_state_dict(sd, strict=True, assign=True)
    except RuntimeError as err:
        raise weights_error(param, path, err) from None
    ctx = net.clip_pretrained.attn_mask.shape[0]  # non-persistent causal mask: rebuild off the meta device
    net.clip_pretrained.attn_mask = torch.full((ctx, ctx), float("-inf")).triu_(1)
    return net.eval()


def window_starts(length: int, crop: int, stride: int) -> list[int]:
    """Window origins along one axis of a padded image (VLMaps' grid: last window clipped at the edge)."""
    n = int(math.ceil(max(length - crop, 0) / stride)) + 1
    return [i * stride for i in range(n)]


class LSegEncoder(Encoder):
    """LSeg (ViT-L/16 + DPT, CLIP ViT-B/32 text space, 512-d); see the module docstring."""

    name = "lseg"
    params_model = LSegParams
    version = "1"

    def __init__(
        self,
        net: LSegNet,
        *,
        weights: Path | None,
        crop_size: int = 480,
        base_size: int = 520,
        stride_rate: float = 2.0 / 3.0,
        out_size: tuple[int, int] = (120, 160),
        device: str = "cpu",
        batch_size: int = 4,
    ):
        super().__init__(device=device, batch_size=batch_size)
        if crop_size % 32:
            raise ValueError(f"crop_size {crop_size} must be a multiple of 32")
        self.net = net.to(self.device).eval()
        self.weights = weights
        self.crop_size, self.base_size = int(crop_size), int(base_size)
        self.stride = max(2, int(crop_size * stride_rate) // 2 * 2)  # even: windows align on the half-res grid
        self.out_size = tuple(out_size)
        self._tokenize = tokenizer()

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "LSegEncoder":
        p = cls.settings(params)
        path = require_file(p.weights, WEIGHTS_PARAM, "the lseg encoder (LSeg checkpoint, e.g. demo_e200.ckpt)")
        return cls(
            load_lseg_net(path),
            weights=path,
            crop_size=p.crop_size,
            base_size=p.base_size,
            stride_rate=p.stride_rate,
            out_size=p.out_size,
            device=device,
            batch_size=batch_size,
        )

    @property
    def dim(self) -> int:
        return self.net.arch.embed_dim

    @property
    def temperature(self) -> float:
        return self.net.temperature

    def config_identity(self) -> dict[str, Any]:
        return {"arch": self.net.arch.name, "crop_size": self.crop_size, "base_size": self.base_size,
                "stride": self.stride, "out_size": list(self.out_size)}

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        with torch.inference_mode():
            return self.net.encode_text(self._tokenize(list(texts)).to(self.device)).float().cpu()

    def _resized_size(self, H: int, W: int) -> tuple[int, int]:
        if H > W:
            return self.base_size, int(1.0 * W * self.base_size / H + 0.5)
        return int(1.0 * H * self.base_size / W + 0.5), self.base_size

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        B, H, W, _ = rgb.shape
        crop, stride = self.crop_size, self.stride
        h, w = self._resized_size(H, W)
        x = normalize(to_tensor01(rgb, self.device), (0.5,) * 3, (0.5,) * 3)
        x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=True)
        ph, pw = max(h, crop), max(w, crop)
        windows = [(y0, x0) for y0 in window_starts(ph, crop, stride) for x0 in window_starts(pw, crop, stride)]
        # every window padded with black (-1 after normalisation) to crop x crop, as VLMaps does
        padded = F.pad(x, (0, pw - w + crop, 0, ph - h + crop), value=-1.0)
        crops = torch.stack([padded[:, :, y0 : y0 + crop, x0 : x0 + crop] for y0, x0 in windows], dim=1)
        crops = crops.reshape(-1, 3, crop, crop)  # (B*nwin, 3, crop, crop), image-major
        hh, hw = (h + 1) // 2, (w + 1) // 2  # the image part of the half-resolution canvas (padding is dropped)
        acc = torch.zeros(B, self.dim, hh, hw, device=self.device)
        count = torch.zeros(1, 1, hh, hw, device=self.device)
        slots = []  # per window: the half-resolution canvas slice it covers (VLMaps clips windows at the edge)
        for y0, x0 in windows:
            y1, x1 = min(y0 + crop, ph), min(x0 + crop, pw)
            sy, sx = y0 // 2, x0 // 2
            slots.append((sy, sx, max(min((y1 - y0 + 1) // 2, hh - sy), 0), max(min((x1 - x0 + 1) // 2, hw - sx), 0)))
            count[:, :, sy : sy + slots[-1][2], sx : sx + slots[-1][3]] += 1
        # windows run batch_size at a time and are added to the canvas at once (no (B*nwin,512,S/2,S/2) buffer)
        for i in range(0, crops.shape[0], self.batch_size):
            feats = self.net.encode_image(crops[i : i + self.batch_size])
            for j in range(feats.shape[0]):
                b, (sy, sx, ry, rx) = divmod(i + j, len(windows))[0], slots[(i + j) % len(windows)]
                acc[b, :, sy : sy + ry, sx : sx + rx] += feats[j, :, :ry, :rx]
        acc.div_(count.clamp_min(1))  # the average of the windows (as VLMaps); resize_features renormalises
        out = resize_features(acc, self.out_size)
        return DenseFeatures(out, all_valid(out), (H, W))
