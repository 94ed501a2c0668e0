"""User-exported encoders: TorchScript files and a python factory, loaded through the params."""

from __future__ import annotations

import pytest
import torch

from pipeline.encoders import build_encoder
from pipeline.errors import ConfigError
from tests.fixtures.dense_encoders import TinyDenseImage, TinyText
from tests.pipeline.encoders.conftest import RUNTIME, encoders_params, toy_batch


def test_scripted_files_reproduce_the_eager_modules(params):
    enc = build_encoder(params, "torchscript", runtime=RUNTIME)
    rgb, _, _ = toy_batch(2)
    out = enc.encode_images(rgb)
    x = torch.from_numpy(rgb).permute(0, 3, 1, 2).float() / 255.0
    ref = TinyDenseImage().eval()(x).permute(0, 2, 3, 1)
    ref = ref / ref.norm(dim=-1, keepdim=True)
    assert out.size == (6, 8) and torch.allclose(out.features, ref, atol=1e-5)
    text = TinyText().eval()(["chair"])
    assert torch.allclose(enc.encode_text(["chair"]), text / text.norm(), atol=1e-6)
    ident = enc.identity()
    assert ident["image_file"] == "image.pt" and ident["text_digest"].startswith("blake2b:")


def test_factory_path(tiny_clip, torchscript_files):
    p = encoders_params(tiny_clip, torchscript_files,
                        torchscript={"image_file": None, "text_file": None,
                                     "factory": "tests.fixtures.dense_encoders:make", "name": "my-encoder"})
    enc = build_encoder(p, "torchscript", runtime=RUNTIME)
    assert enc.name == "my-encoder" and enc.temperature == 0.05 and enc.dim == 16
    assert enc.identity()["factory"] == "tests.fixtures.dense_encoders:make"
    bad = encoders_params(tiny_clip, torchscript_files,
                          torchscript={"image_file": None, "text_file": None, "factory": "tests.fixtures:nothing"})
    with pytest.raises(ConfigError, match=r"encoders\.torchscript\.factory 'tests\.fixtures:nothing'"):
        build_encoder(bad, "torchscript", runtime=RUNTIME)


def test_a_file_that_is_not_torchscript(tmp_path, tiny_clip, torchscript_files):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"junk")
    p = encoders_params(tiny_clip, torchscript_files, torchscript={"image_file": str(junk)})
    with pytest.raises(ConfigError, match=rf"encoders\.torchscript\.image_file: {junk} is not a TorchScript module"):
        build_encoder(p, "torchscript", runtime=RUNTIME)
