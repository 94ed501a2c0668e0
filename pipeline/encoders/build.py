"""Building the encoder a stage or a name chooses, and checking it on a synthetic frame.

Apart from :mod:`pipeline.encoders.base` (the interface and registry the implementations import) so that the base
never imports :mod:`pipeline.encoders.choice`, which imports the implementations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from pipeline import plugins
from pipeline.encoders.base import ENCODERS, Encoder, resolve_device
from pipeline.encoders.choice import encoder_choice, load

if TYPE_CHECKING:
    from pipeline.config import EncodersParams, RunParams


def build_encoder(params: "EncodersParams", which: str | None = None, *, simulated: bool = False,
                  runtime: "RunParams | None" = None) -> Encoder:
    """Build the encoder chosen in ``params`` for a map stage (``which`` = 'vlmap' / 'cfmap') or by name.

    ``runtime`` (the ``run`` section: device, batch size, torch threads; defaults when None) never changes
    the features' identity, so it is in no digest.
    """
    from pipeline.config import RunParams

    runtime = runtime or RunParams()
    name = encoder_choice(params, which, simulated=simulated)
    load(name)
    if runtime.torch_threads:
        torch.set_num_threads(runtime.torch_threads)
    device = resolve_device(runtime.device)
    cls = ENCODERS[name]
    with plugins.running(cls, "from_params"):
        encoder = cls.from_params(params, device=device, batch_size=runtime.encoder_batch_size)  # type: ignore
    encoder.precision = runtime.precision
    return encoder


def check_encoder(params: "EncodersParams", which: str | None = None, *, simulated: bool = False,
                  runtime: "RunParams | None" = None) -> dict[str, Any]:
    """Build the configured encoder, run it on one synthetic frame and a query; return its identity + shapes.

    For a CLI ``zipon encoders check``: it proves the weights load and the output contract holds,
    without touching any scene. The oracle is checked against a one-object synthetic scene.
    """
    enc = build_encoder(params, which, simulated=simulated, runtime=runtime)
    rgb = np.zeros((1, 240, 320, 3), np.uint8)
    rgb[:, 60:180, 80:240] = (180, 40, 40)
    depth = np.full((1, 240, 320), 2.0, np.float32)
    instance = np.zeros((1, 240, 320), np.uint16)
    instance[:, 60:180, 80:240] = 1
    if enc.diagnostic or enc.needs_ground_truth:
        from pipeline.scene_gt import GTScene

        enc.bind_scene(GTScene.model_validate({
            "name": "check", "seed": 0, "wall_height_m": 2.5, "rooms": [], "walls": [],
            "objects": [{"id": 1, "cls": "chair", "room": "r", "parts": [{"min": (0, 0, 0), "max": (1, 1, 1)}],
                         "color_name": "red", "color_rgb": (180, 40, 40), "material": "wood", "size": "big"}],
        }))
    out = enc.encode_images(rgb, depth_m=depth, instance=instance)
    text = enc.encode_text(["a chair"])
    return {
        "identity": enc.identity(),
        "device": str(enc.device),
        "feature_grid": list(out.size),
        "valid_fraction": float(out.valid.float().mean()),
        "text_shape": list(text.shape),
    }
