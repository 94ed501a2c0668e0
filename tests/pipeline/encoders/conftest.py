"""Shared encoder fixtures: tiny random-init models saved to tmp files and loaded through the real code."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

os.environ["HF_HUB_OFFLINE"] = "1"

from pipeline.config import EncodersParams, RunParams  # noqa: E402
from pipeline.scene_gt import GTScene  # noqa: E402
from tests.fixtures import dense_encoders as de  # noqa: E402

IMAGE_HW = (48, 64)


@pytest.fixture(scope="session")
def tiny_clip(tmp_path_factory) -> tuple[str, str]:
    """(arch name, weights path) of a registered tiny open_clip ViT."""
    folder = tmp_path_factory.mktemp("tiny_clip")
    arch = de.register_tiny_clip(folder)
    return arch, str(de.save_tiny_clip_weights(folder / "tiny_clip.pt"))


@pytest.fixture(scope="session")
def torchscript_files(tmp_path_factory) -> tuple[str, str]:
    image, text = de.save_torchscript_pair(tmp_path_factory.mktemp("ts"))
    return str(image), str(text)


@pytest.fixture(scope="session")
def lseg_ckpt(tmp_path_factory) -> str:
    """A random-init tiny LSeg saved as a pytorch-lightning style checkpoint (``state_dict`` with ``net.`` keys)."""
    from pipeline.encoders.lseg_net import LSegNet, tiny_arch

    torch.manual_seed(3)
    net = LSegNet(tiny_arch())
    with torch.no_grad():  # non-trivial batch-norm statistics, so the round trip checks them too
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.5, 1.5)
    path = tmp_path_factory.mktemp("lseg") / "tiny_lseg.ckpt"
    torch.save({"epoch": 1, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, path)
    return str(path)


def gt_scene() -> GTScene:
    """Three objects: a red chair (1), a blue chair (2), a wooden table (3)."""
    def obj(i, cls, color, rgb, material):
        return {"id": i, "cls": cls, "room": "r", "parts": [{"min": (i, 0, 0), "max": (i + 0.5, 0.5, 0.8)}],
                "color_name": color, "color_rgb": rgb, "material": material, "size": "big"}

    return GTScene.model_validate({
        "name": "toy", "seed": 0, "wall_height_m": 2.5,
        "rooms": [{"id": "r", "type": "living room", "polygon": [(0, 0), (5, 0), (5, 5), (0, 5)]}],
        "walls": [],
        "objects": [obj(1, "chair", "red", (200, 20, 20), "fabric"), obj(2, "chair", "dark blue", (20, 20, 120),
                                                                           "fabric"),
                    obj(3, "dining table", "brown", (120, 80, 40), "wood")],
    })


def toy_batch(n: int = 3, seed: int = 0):
    """``n`` frames: coloured blocks with a depth step and matching instance ids (0 = background)."""
    H, W = IMAGE_HW
    rng = np.random.default_rng(seed)
    rgb = np.full((n, H, W, 3), 90, np.uint8)
    depth = np.full((n, H, W), 3.0, np.float32)
    inst = np.zeros((n, H, W), np.uint16)
    for b in range(n):
        x0 = 4 + 6 * b
        rgb[b, 8:30, x0 : x0 + 20] = (200, 20, 20)
        depth[b, 8:30, x0 : x0 + 20] = 1.5
        inst[b, 8:30, x0 : x0 + 20] = 1
        rgb[b, 20:44, 40:60] = (20, 20, 120)
        depth[b, 20:44, 40:60] = 2.0
        inst[b, 20:44, 40:60] = 2
    rgb = np.clip(rgb.astype(np.int16) + rng.integers(-5, 6, rgb.shape), 0, 255).astype(np.uint8)
    return rgb, depth, inst


# devices, batch sizes and threads are run settings (in no digest); the tests run small batches on the CPU
RUNTIME = RunParams(device="cpu", encoder_batch_size=2)


def encoders_params(tiny_clip, torchscript_files, **extra) -> EncodersParams:
    arch, weights = tiny_clip
    image, text = torchscript_files
    raw = {
        "maskclip": {"arch": arch, "weights": weights, "input_size": (48, 64)},
        "conceptfusion": {"arch": arch, "weights": weights, "out_size": (12, 16),
                          "regions": {"generator": "rgbd", "work_height": 48}},
        "torchscript": {"image_file": image, "text_file": text},
        "oracle": {"dim": 64, "out_size": (12, 16)},
    }
    for k, v in extra.items():
        raw[k] = {**raw.get(k, {}), **v} if isinstance(v, dict) else v
    return EncodersParams.model_validate(raw)


@pytest.fixture(scope="session")
def params(tiny_clip, torchscript_files) -> EncodersParams:
    return encoders_params(tiny_clip, torchscript_files)
