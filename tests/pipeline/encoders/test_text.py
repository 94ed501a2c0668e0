"""Torch-free text sides (pipeline.encoders.text): the same features and identity as the whole encoders."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from pipeline.config import EncodersParams
from pipeline.encoders import build_encoder
from pipeline.encoders.text import text_encoder
from tests.pipeline.encoders.conftest import RUNTIME, gt_scene

PROMPTS = ["chair", "the red couch", "wooden table", "floor", "purple elephant spaceship"]


@pytest.mark.parametrize("name", ["oracle", "simulated_lseg", "simulated_cf"])
def test_text_side_gives_the_encoders_features_and_identity(name):
    params = EncodersParams()
    full = build_encoder(params, name, runtime=RUNTIME)
    text = text_encoder(params, name)
    gt = gt_scene()
    full.bind_scene(gt)
    text.bind_scene(gt)
    got = text.encode_text(PROMPTS)
    assert isinstance(got, np.ndarray) and got.dtype == np.float32 and got.shape == (len(PROMPTS), full.dim)
    assert np.array_equal(got, full.encode_text(PROMPTS).numpy())
    ident = full.identity()
    assert {k: v for k, v in text.identity().items()} == {k: ident[k] for k in text.identity()}
    assert (text.name, text.dim, text.temperature) == (full.name, full.dim, full.temperature)


def test_encoders_with_a_model_have_no_text_side():
    assert text_encoder(EncodersParams(), "maskclip") is None and text_encoder(EncodersParams(), "lseg") is None


def test_text_sides_import_no_torch():
    code = ("import json, sys\nfrom pipeline.config import EncodersParams\nfrom pipeline.encoders.text import "
            "text_encoder\nfor n in ('oracle', 'simulated_lseg', 'simulated_cf'):\n"
            "    text_encoder(EncodersParams(), n).encode_text(['chair'])\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'open3d'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "HF_HUB_OFFLINE": "1"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.splitlines()[-1]) == []
