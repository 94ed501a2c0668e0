"""ConceptFusion: the fusion formula, batched crops, invalid cells outside every region."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.encoders import build_encoder
from pipeline.encoders.conceptfusion import fuse_region_features
from tests.pipeline.encoders.conftest import RUNTIME, encoders_params, toy_batch


def test_fusion_matches_the_paper_formula():
    rng = np.random.default_rng(0)
    g = rng.standard_normal((2, 8))
    local = rng.standard_normal((5, 8))
    frame_of = np.array([0, 0, 0, 1, 1])
    got = fuse_region_features(torch.tensor(g), torch.tensor(local), torch.tensor(frame_of), 2, 0.5).numpy()
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)  # noqa: E731
    for f in range(2):
        gi, li = unit(g[f]), unit(local[frame_of == f])
        cos = li @ gi
        w = np.exp(cos / 0.5) / np.exp(cos / 0.5).sum()
        ref = unit(w[:, None] * gi + (1 - w[:, None]) * li)
        np.testing.assert_allclose(got[frame_of == f], ref, atol=1e-9)


@pytest.fixture(scope="module")
def gt_encoder(tiny_clip, torchscript_files):
    p = encoders_params(tiny_clip, torchscript_files,
                        conceptfusion={"regions": {"generator": "gt", "gt_background": False, "work_height": 48}})
    return build_encoder(p, "conceptfusion", runtime=RUNTIME)


def test_cells_outside_regions_are_invalid_not_zero_filled(gt_encoder):
    rgb, depth, inst = toy_batch(3)
    out = gt_encoder.encode_images(rgb, depth_m=depth, instance=inst)
    ids = inst[:, 2::4, 2::4]  # cell centres of the 12x16 grid on 48x64 images
    assert torch.equal(out.valid, torch.from_numpy(ids > 0))
    assert torch.all(out.features[~out.valid] == 0)
    f0 = out.features[0]
    red, blue = f0[torch.from_numpy(ids[0] == 1)], f0[torch.from_numpy(ids[0] == 2)]
    assert torch.allclose(red, red[:1].expand_as(red)) and torch.allclose(blue, blue[:1].expand_as(blue))
    assert (red[0] @ blue[0]) < 0.9999  # regions get their own fused features


def test_region_crops_are_batched_across_regions_and_frames(gt_encoder):
    rgb, depth, inst = toy_batch(3)
    crops: list[int] = []

    def count(module, inputs, output):
        crops.append(len(inputs[0]))

    hook = gt_encoder.model.visual.register_forward_hook(count)
    try:
        gt_encoder.encode_images(rgb, depth_m=depth, instance=inst)
    finally:
        hook.remove()
    assert sum(crops) == 3 * 3  # per frame: the whole image + 2 instance regions
    assert len(crops) == 2  # batch_size 2: one CLIP pass for frames 0-1, one for frame 2


def test_default_rgbd_regions_cover_the_objects(params):
    enc = build_encoder(params, "conceptfusion", runtime=RUNTIME)
    rgb, depth, inst = toy_batch(2)
    out = enc.encode_images(rgb, depth_m=depth)
    ids = inst[:, 2::4, 2::4]
    assert out.valid.float().mean() > 0.9
    # cells of one object share a region feature: object cells agree more with each other than with the other object
    f = out.features[0]
    red, blue = f[torch.from_numpy(ids[0] == 1)], f[torch.from_numpy(ids[0] == 2)]
    assert (red @ red.T).mean() > (red @ blue.T).mean()


def test_crops_are_exact_at_scale_one_and_batched_over_frames():
    from pipeline.encoders.conceptfusion import cut_crops

    x = torch.rand(2, 3, 40, 50)
    boxes = [torch.tensor([[5.0, 3.0, 21.0, 19.0]]), torch.tensor([[0.0, 0.0, 16.0, 16.0], [30.0, 20.0, 46.0, 36.0]])]
    crops = cut_crops(x, boxes, (16, 16))
    assert crops.shape == (3, 3, 16, 16)
    assert torch.allclose(crops[0], x[0, :, 3:19, 5:21], atol=1e-6)
    assert torch.allclose(crops[2], x[1, :, 20:36, 30:46], atol=1e-6)
    big = cut_crops(x, [torch.tensor([[0.0, 0.0, 50.0, 40.0]])], (8, 8))  # > 2x: from the antialiased half image
    assert big.shape == (1, 3, 8, 8) and (big - x.mean(dim=(2, 3))[0, :, None, None]).abs().mean() < 0.2


class _Overlapping:
    """Two overlapping regions (as SAM gives): left 2/3 and right 2/3 of the frame."""

    def __init__(self, params):
        self.params = params

    def __call__(self, rgb, depth_m, instance):
        from pipeline.encoders.regions import Regions

        masks = np.zeros((2, 12, 16), bool)
        masks[0, :, :10] = True
        masks[1, :, 6:] = True
        return Regions(masks, rgb.shape[:2])


def test_overlapping_regions_sum_and_renormalise(gt_encoder):
    from pipeline.encoders.conceptfusion import ConceptFusionEncoder

    enc = ConceptFusionEncoder(gt_encoder.model, _Overlapping(gt_encoder.regions.params), arch=gt_encoder.arch,
                               weights=None, out_size=(12, 16))
    rgb, _, _ = toy_batch(1)
    out = enc.encode_images(rgb)
    f = out.features[0]
    a, b, both = f[0, 0], f[0, 15], f[0, 8]
    assert out.valid.all()
    expected = (a + b) / (a + b).norm()
    assert torch.allclose(both, expected, atol=1e-5)
