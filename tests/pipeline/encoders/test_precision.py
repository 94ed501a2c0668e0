"""Devices and mixed precision of the encoders: ``run.device`` names a GPU by index, a GPU that is not there is a
clear error, and features computed under bf16 autocast match fp32 on a real TUM frame (random weights)."""

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from pydantic import ValidationError

from pipeline.config import RunParams
from pipeline.encoders import build_encoder
from pipeline.encoders.base import resolve_device
from pipeline.encoders.lseg import LSegEncoder, load_lseg_net
from pipeline.encoders.lseg_net import tiny_arch
from pipeline.errors import ConfigError
from tests.fixtures.real_data import TUM_RPY

from tests.pipeline.encoders.conftest import RUNTIME


def tum_frame() -> np.ndarray:
    """The first colour frame of the TUM fr1/rpy sample, ``(1, 480, 640, 3)`` uint8."""
    return np.array(Image.open(sorted((TUM_RPY / "rgb").iterdir())[0]).convert("RGB"))[None]


def test_a_device_is_cpu_cuda_cuda_n_or_auto():
    assert RunParams(device="cuda:1", fusion_device="cuda:0").device == "cuda:1"
    with pytest.raises(ValidationError, match="'gpu0' is not a device: use cpu, cuda, cuda:N"):
        RunParams(device="gpu0")
    with pytest.raises(ValidationError, match="resource amounts must be positive"):
        RunParams(encoder_resources={"GPU": 0})


def test_a_gpu_index_torch_does_not_see_is_an_error_naming_the_key():
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    with pytest.raises(ConfigError, match=rf"run\.fusion_device: 'cuda:{count}' requested but torch sees {count} CUDA"):
        resolve_device(f"cuda:{count}", "run.fusion_device")
    assert resolve_device("cpu") == "cpu" and resolve_device("auto") in ("cpu", "cuda")


def _cosine(a: torch.Tensor, b: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)[valid]


@pytest.mark.parametrize("name", ["maskclip", "conceptfusion"])
def test_bf16_features_match_fp32_on_a_real_frame(params, name):
    rgb = tum_frame()
    depth = np.full(rgb.shape[:3], 1.5, np.float32)
    fp32 = build_encoder(params, name, runtime=RUNTIME)
    bf16 = build_encoder(params, name, runtime=RUNTIME.model_copy(update={"precision": "bf16"}))
    a, b = (e.encode_images(rgb, depth_m=depth) for e in (fp32, bf16))
    assert b.features.dtype == torch.float32 and torch.equal(a.valid, b.valid)
    cos = _cosine(a.features, b.features, a.valid)
    assert cos.numel() > 0 and float(cos.mean()) >= 0.999 and float(cos.min()) >= 0.99, (float(cos.mean()),
                                                                                           float(cos.min()))
    assert not torch.equal(a.features, b.features)  # autocast did run the forward pass in bf16
    assert "precision" not in fp32.identity() and bf16.identity()["precision"] == "bf16"  # the map records it


def test_bf16_lseg_matches_fp32_on_a_real_frame(lseg_ckpt):
    net = load_lseg_net(Path(lseg_ckpt), tiny_arch())
    encoders = []
    for precision in ("fp32", "bf16"):
        enc = LSegEncoder(net, weights=Path(lseg_ckpt), crop_size=64, base_size=80, out_size=(24, 32), batch_size=1)
        enc.precision = precision
        encoders.append(enc)
    a, b = (e.encode_images(tum_frame()) for e in encoders)
    cos = _cosine(a.features, b.features, a.valid)
    assert not torch.equal(a.features, b.features)
    assert float(cos.mean()) >= 0.999 and float(cos.min()) >= 0.99, (float(cos.mean()), float(cos.min()))


@pytest.mark.parametrize("setting, message", [
    ("run: {device: gpu0}", "params.yaml: run.device: 'gpu0' is not a device: use cpu, cuda, cuda:N"),
    ("run: {device: 'cuda:7'}", "run.device: 'cuda:7' requested but torch sees"),
])
def test_a_bad_device_is_one_line_and_exit_1(setting, message, tmp_path, capsys):
    from zipon.cli import main

    p = tmp_path / "params.yaml"
    p.write_text("scenes:\n  a: {source: simulate}\n" + setting + "\n")
    assert main(["-p", str(p), "encoders", "check", "--which", "vlmap"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert message in err and "Traceback" not in err
