"""MaskCLIP: the token path is open_clip's; in the last block each token attends only to itself."""

from __future__ import annotations

import open_clip
import pytest
import torch

from pipeline.encoder_params.maskclip import MaskClipParams
from pipeline.encoders import build_encoder
from pipeline.encoders.maskclip import maskclip_patch_features, vit_tokens
from pipeline.errors import ConfigError
from tests.pipeline.encoders.conftest import RUNTIME, encoders_params, toy_batch


@pytest.fixture(scope="module")
def encoder(params):
    return build_encoder(params, "maskclip", runtime=RUNTIME)


def test_token_path_is_open_clips(encoder):
    visual = encoder.model.visual
    x = torch.randn(2, 3, 64, 64)  # the model's native size: no position-embedding resampling
    with torch.inference_mode():
        tokens = vit_tokens(visual, x, len(visual.transformer.resblocks))
        pooled = visual.ln_post(tokens[:, 0]) @ visual.proj
        assert torch.allclose(pooled, encoder.model.encode_image(x), atol=1e-5)


def test_last_block_is_the_block_with_each_token_attending_only_to_itself(encoder):
    visual = encoder.model.visual
    x = torch.randn(2, 3, 64, 64)
    last = visual.transformer.resblocks[-1]
    with torch.inference_mode():
        before = vit_tokens(visual, x, len(visual.transformer.resblocks) - 1)
        # MaskCLIP's rule (its mmseg ViT, return_qkv): x + out_proj(v), then the block's MLP with residual =
        # open_clip's own block run with attention restricted to each token itself
        n = before.shape[1]
        self_only = torch.full((n, n), float("-inf")).fill_diagonal_(0.0)
        out = last(before, attn_mask=self_only)[:, 1:]
        expected = (visual.ln_post(out) @ visual.proj).transpose(1, 2).reshape(2, -1, 4, 4)
        got = maskclip_patch_features(visual, x)
        # not the bare value path (no residual, no MLP): that one differs
        C = before.shape[-1]
        bare = last.attn.out_proj(torch.nn.functional.linear(
            last.ln_1(before[:, 1:]), last.attn.in_proj_weight[2 * C :], last.attn.in_proj_bias[2 * C :]))
        bare = (visual.ln_post(bare) @ visual.proj).transpose(1, 2).reshape(2, -1, 4, 4)
    assert torch.allclose(got, expected, atol=1e-5)
    assert not torch.allclose(got, bare, atol=1e-2)


def test_patch_grid_follows_input_size(encoder):
    rgb, _, _ = toy_batch(2)
    out = encoder.encode_images(rgb)
    assert out.size == (3, 4)  # input 48x64 with 16-pixel patches
    assert encoder.dim == 32 and encoder.identity()["input_size"] == [48, 64]


def test_default_is_vit_b32_in_the_512d_text_space():
    assert MaskClipParams().arch == "ViT-B-32"
    assert open_clip.get_model_config("ViT-B-32")["embed_dim"] == 512


def test_input_size_must_fit_the_patches(tiny_clip, torchscript_files):
    p = encoders_params(tiny_clip, torchscript_files, maskclip={"input_size": (50, 64)})
    with pytest.raises(ConfigError, match=r"encoders\.maskclip\.input_size \(50, 64\) must be multiples"):
        build_encoder(p, "maskclip", runtime=RUNTIME)
