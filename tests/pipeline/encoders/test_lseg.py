"""LSeg: public checkpoint layout, checkpoint round trip, strict loading, VLMaps' sliding window."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from pipeline.encoders.base import resize_features
from pipeline.encoders.lseg import LSegEncoder, load_lseg_net, window_starts
from pipeline.encoders.lseg_net import LSegNet, tiny_arch
from pipeline.errors import ConfigError
from tests.fixtures.lseg_layout import expected_lseg_layout
from tests.pipeline.encoders.conftest import toy_batch


def test_full_size_layout_matches_public_checkpoint():
    with torch.device("meta"):  # 495M parameters: shapes only, nothing allocated
        net = LSegNet()
    got = {f"net.{k}": tuple(v.shape) for k, v in net.state_dict().items()}
    expected = expected_lseg_layout()
    assert sorted(set(expected) - set(got)) == []
    assert sorted(set(got) - set(expected)) == []
    assert {k: v for k, v in got.items() if expected[k] != v} == {}
    assert len(got) == 730
    with torch.device("meta"):  # and a 480 px window gives 512-d features on the 240x240 head grid
        assert net.eval().encode_image(torch.empty(2, 3, 480, 480)).shape == (2, 512, 240, 240)


def test_checkpoint_round_trip_gives_identical_outputs(lseg_ckpt):
    torch.manual_seed(3)
    ref = LSegNet(tiny_arch()).eval()
    sd = torch.load(lseg_ckpt, weights_only=True)["state_dict"]
    ref.load_state_dict({k[4:]: v for k, v in sd.items()})
    loaded = load_lseg_net(Path(lseg_ckpt), tiny_arch())
    x = torch.randn(2, 3, 64, 96)
    tokens = torch.randint(1, 49000, (3, 77))
    with torch.inference_mode():
        assert torch.equal(ref.encode_image(x), loaded.encode_image(x))
        assert torch.equal(ref.encode_text(tokens), loaded.encode_text(tokens))


def test_bare_state_dict_and_fp16_parts_load(tmp_path, lseg_ckpt):
    sd = torch.load(lseg_ckpt, weights_only=True)["state_dict"]
    bare = {k[4:]: (v.half() if k.startswith("net.clip_pretrained") and v.is_floating_point() else v)
            for k, v in sd.items()}
    path = tmp_path / "bare.pt"
    torch.save(bare, path)
    net = load_lseg_net(path, tiny_arch())
    assert net.clip_pretrained.token_embedding.weight.dtype == torch.float32


def test_strict_loading_names_param_file_and_key(tmp_path, lseg_ckpt):
    sd = torch.load(lseg_ckpt, weights_only=True)["state_dict"]
    del sd["net.scratch.head1.bias"]
    sd["net.scratch.extra.weight"] = torch.zeros(1)
    path = tmp_path / "broken.ckpt"
    torch.save({"state_dict": sd}, path)
    with pytest.raises(ConfigError, match=rf"encoders\.lseg\.weights: {path} does not match the model") as err:
        load_lseg_net(path, tiny_arch())
    assert "scratch.head1.bias" in str(err.value)


def test_vlmaps_window_grid_on_480x640():
    enc = LSegEncoder.__new__(LSegEncoder)
    enc.base_size = 520
    assert enc._resized_size(480, 640) == (390, 520)
    assert enc._resized_size(640, 480) == (520, 390)
    assert window_starts(480, 480, 320) == [0]  # 390 rows padded to 480
    assert window_starts(520, 480, 320) == [0, 320]


def vlmaps_reference(net: LSegNet, rgb: np.ndarray, crop: int, base: int) -> torch.Tensor:
    """VLMaps' get_lseg_feat, written out at full resolution (per image, per window)."""
    outs = []
    for img in rgb:
        x = (torch.from_numpy(img).permute(2, 0, 1).float()[None] / 255.0 - 0.5) / 0.5
        h, w = x.shape[2:]
        H, W = (int(h * base / w + 0.5), base) if w >= h else (base, int(w * base / h + 0.5))
        x = F.interpolate(x, size=(H, W), mode="bilinear", align_corners=True)
        x = F.pad(x, (0, max(crop - W, 0), 0, max(crop - H, 0)), value=-1.0)
        ph, pw = x.shape[2:]
        stride = int(crop * 2 / 3)
        acc = torch.zeros(1, net.arch.embed_dim, ph, pw)
        cnt = torch.zeros(1, 1, ph, pw)
        for i in range(int(math.ceil((ph - crop) / stride)) + 1):
            for j in range(int(math.ceil((pw - crop) / stride)) + 1):
                h0, w0 = i * stride, j * stride
                h1, w1 = min(h0 + crop, ph), min(w0 + crop, pw)
                c = F.pad(x[:, :, h0:h1, w0:w1], (0, crop - (w1 - w0), 0, crop - (h1 - h0)), value=-1.0)
                f = F.interpolate(net.encode_image(c), scale_factor=2, mode="bilinear", align_corners=True)
                acc[:, :, h0:h1, w0:w1] += f[:, :, : h1 - h0, : w1 - w0]
                cnt[:, :, h0:h1, w0:w1] += 1
        outs.append((acc / cnt)[:, :, :H, :W])
    return torch.cat(outs)


def test_sliding_window_matches_vlmaps_reference(lseg_ckpt):
    net = load_lseg_net(Path(lseg_ckpt), tiny_arch())
    enc = LSegEncoder(net, weights=Path(lseg_ckpt), crop_size=64, base_size=80, out_size=(12, 16), batch_size=3)
    rgb, _, _ = toy_batch(2)
    out = enc.encode_images(rgb)
    assert out.features.shape == (2, 12, 16, 32) and out.valid.all()
    with torch.inference_mode():
        ref = resize_features(vlmaps_reference(net, rgb, 64, 80), (12, 16))
    cos = (out.features * ref).sum(-1)
    assert cos.min() > 0.999, float(cos.min())  # stitching at half resolution = bilinear x2 then stitching
    assert enc.identity()["temperature"] == pytest.approx(0.07)
