"""The encoder contract, run against every implementation, plus the factory and its errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.encoders import ENCODERS, DenseFeatures, Encoder, build_encoder, encoder_choice
from pipeline.encoders.lseg import LSegEncoder, load_lseg_net
from pipeline.encoders.lseg_net import tiny_arch
from pipeline.errors import ConfigError, InputDataError, MissingInputError
from pipeline.geometry import Intrinsics
from tests.pipeline.encoders.conftest import RUNTIME, IMAGE_HW, encoders_params, gt_scene, toy_batch


def make_encoder(name: str, params, lseg_ckpt: str) -> Encoder:
    if name == "lseg":  # the public network is too big for unit tests: same code, reduced sizes
        return LSegEncoder(load_lseg_net(Path(lseg_ckpt), tiny_arch()), weights=Path(lseg_ckpt), crop_size=64,
                           base_size=80, out_size=(12, 16), batch_size=RUNTIME.encoder_batch_size)
    enc = build_encoder(params, name, runtime=RUNTIME)
    enc.bind_scene(gt_scene())
    return enc


@pytest.fixture(scope="module", params=sorted(ENCODERS))
def encoder(request, params, lseg_ckpt) -> Encoder:
    return make_encoder(request.param, params, lseg_ckpt)


class TestEncoderContract:
    """Every encoder: shapes, dtypes, normalisation, validity, text space, identity, batching."""

    @pytest.fixture(scope="class")
    def batch(self):
        return toy_batch(3)

    @pytest.fixture
    def out(self, encoder, batch) -> DenseFeatures:
        rgb, depth, inst = batch
        return encoder.encode_images(rgb, depth_m=depth, instance=inst)

    def test_features_shape_and_norm(self, encoder, out):
        B = 3
        assert out.features.dtype == torch.float32 and out.valid.dtype == torch.bool
        assert out.features.shape[0] == B and out.features.shape[-1] == encoder.dim
        assert out.valid.shape == out.features.shape[:3]
        assert out.image_size == IMAGE_HW
        norms = out.features.norm(dim=-1)
        assert out.valid.any()
        assert torch.allclose(norms[out.valid], torch.ones(()), atol=1e-4)
        assert torch.all(norms[~out.valid] == 0)

    def test_text_in_same_space(self, encoder, out):
        t = encoder.encode_text(["chair", "a red chair", "floor"])
        assert t.shape == (3, encoder.dim) and t.dtype == torch.float32
        assert torch.allclose(t.norm(dim=-1), torch.ones(3), atol=1e-5)
        scores = torch.einsum("bhwd,td->bhwt", out.features, t)
        assert torch.isfinite(scores).all() and scores.abs().max() <= 1 + 1e-4

    def test_identity_is_json(self, encoder):
        ident = encoder.identity()
        assert json.loads(json.dumps(ident)) == ident
        assert ident["name"] == encoder.name and ident["dim"] == encoder.dim
        assert ident["normalization"] == "l2" and ident["diagnostic"] is (encoder.name == "oracle")
        if encoder.name == "oracle":
            assert "DIAGNOSTIC" in ident["kind"]
        else:
            assert any(k.endswith("digest") for k in ident)

    def test_batching_does_not_change_features(self, encoder, batch, out):
        rgb, depth, inst = batch
        old = encoder.batch_size
        encoder.batch_size = 1
        try:
            one = encoder.encode_images(rgb, depth_m=depth, instance=inst)
        finally:
            encoder.batch_size = old
        assert torch.equal(one.valid, out.valid)
        assert torch.allclose(one.features, out.features, atol=1e-5)

    def test_bad_input_names_the_field(self, encoder, batch):
        rgb, depth, _ = batch
        with pytest.raises(InputDataError, match="field rgb"):
            encoder.encode_images(rgb.astype(np.float32))
        with pytest.raises(InputDataError, match="field depth_m"):
            encoder.encode_images(rgb, depth_m=depth[:, :10])

    def test_feature_grid_intrinsics(self, out):
        H, W = IMAGE_HW
        intr = Intrinsics.from_hfov(W, H, 90.0)
        h, w = out.size
        fi = out.intrinsics(intr)
        assert (fi.width, fi.height) == (w, h)
        # the image centre is the feature grid's centre
        assert fi.cx == pytest.approx((intr.cx + 0.5) * w / W - 0.5)
        assert out.resample_depth(np.ones((3, H, W), np.float32)).shape == (3, h, w)


# ----------------------------------------------------------------------------- factory and errors

def test_every_encoder_has_a_params_section():
    from pipeline.config import EncodersParams

    assert set(ENCODERS) == set(EncodersParams.model_fields) & set(ENCODERS)
    for name in ENCODERS:
        assert name in EncodersParams.model_fields


def test_real_encoder_without_weights_is_a_config_error():
    from pipeline.config import EncodersParams

    p = EncodersParams()
    for name in ("lseg", "maskclip", "conceptfusion"):
        with pytest.raises(ConfigError, match=rf"encoders\.{name}\.weights is not set"):
            build_encoder(p, name, runtime=RUNTIME)
    with pytest.raises(ConfigError, match=r"encoders\.torchscript\.image_file is not set"):
        build_encoder(p, "torchscript", runtime=RUNTIME)


def test_missing_weights_file_names_param_and_file(tmp_path):
    from pipeline.config import EncodersParams

    missing = tmp_path / "nope.ckpt"
    p = EncodersParams(lseg={"weights": str(missing)})
    with pytest.raises(MissingInputError, match=rf"encoders\.lseg\.weights: weights file {missing} not found"):
        build_encoder(p, "vlmap", runtime=RUNTIME)


def test_wrong_weights_file_names_param_and_file(tmp_path, tiny_clip, torchscript_files):
    arch, weights = tiny_clip
    p = encoders_params(tiny_clip, torchscript_files, maskclip={"arch": "ViT-B-32"})  # tiny weights, big arch
    with pytest.raises(ConfigError, match=rf"encoders\.maskclip\.weights: {weights} does not match the model"):
        build_encoder(p, "maskclip", runtime=RUNTIME)
    garbage = tmp_path / "garbage.ckpt"
    garbage.write_bytes(b"not a checkpoint")
    p = encoders_params(tiny_clip, torchscript_files, lseg={"weights": str(garbage)})
    with pytest.raises(ConfigError, match=rf"encoders\.lseg\.weights: {garbage} does not match"):
        build_encoder(p, "lseg", runtime=RUNTIME)


def test_choice_per_stage_and_simulated_override(params):
    assert encoder_choice(params, "vlmap") == "lseg"
    assert encoder_choice(params, "cfmap") == "conceptfusion"
    unset = params.model_copy(update={"simulated": None})
    assert encoder_choice(unset, "cfmap", simulated=True) == "conceptfusion"  # not overridden unless set
    assert encoder_choice(params, "cfmap", simulated=True) == "simulated_cf"  # the default for simulated scenes
    sim = params.model_copy(update={"simulated": "oracle"})
    assert encoder_choice(sim, "vlmap", simulated=True) == "oracle"
    assert encoder_choice(sim, "vlmap", simulated=False) == "lseg"
    enc = build_encoder(sim, "vlmap", simulated=True, runtime=RUNTIME)
    assert enc.name == "oracle" and enc.identity()["diagnostic"] is True
    with pytest.raises(ConfigError, match="unknown"):
        encoder_choice(params, "clipseg")


def test_params_validation_names_the_key():
    from pipeline.paramsfile import parse_params

    with pytest.raises(ConfigError, match=r"encoders\.vlmap"):
        parse_params({"scenes": {}, "encoders": {"vlmap": "clipseg"}})
    with pytest.raises(ConfigError, match=r"encoders\.lseg\.crop_size"):
        parse_params({"scenes": {}, "encoders": {"lseg": {"crop_size": 100}}})


def test_threads_and_device_params(params):
    before = torch.get_num_threads()
    try:
        build_encoder(params, "oracle", runtime=RUNTIME.model_copy(update={"torch_threads": 1}))
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"run\.device: 'cuda' requested"):
            build_encoder(params, "oracle", runtime=RUNTIME.model_copy(update={"device": "cuda"}))
        auto = RUNTIME.model_copy(update={"device": "auto"})
        assert build_encoder(params, "maskclip", runtime=auto).device.type == "cpu"


def test_check_encoder_reports_identity_and_shapes(params):
    from pipeline.encoders import check_encoder

    report = check_encoder(params.model_copy(update={"simulated": "oracle"}), "vlmap", simulated=True)
    assert report["identity"]["name"] == "oracle" and report["identity"]["diagnostic"] is True
    assert report["feature_grid"] == [12, 16] and report["text_shape"] == [1, 64]
    report = check_encoder(params, "maskclip")
    assert report["feature_grid"] == [3, 4] and report["valid_fraction"] == 1.0
