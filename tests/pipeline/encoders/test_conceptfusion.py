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


def test_crops_go_through_the_models_own_open_clip_eval_transform(gt_encoder):
    from PIL import Image

    from pipeline.encoders.conceptfusion import eval_transform

    rgb, depth, inst = toy_batch(1)
    seen: list[torch.Tensor] = []
    hook = gt_encoder.model.visual.register_forward_hook(lambda m, i, o: seen.append(i[0].clone()))
    try:
        gt_encoder.encode_images(rgb, depth_m=depth, instance=inst)
    finally:
        hook.remove()
    tf = eval_transform(gt_encoder.model)  # shorter side to the input size, centre crop, CLIP normalisation
    image = Image.fromarray(rgb[0])
    # the whole frame, then the instance boxes (largest first): red block 22x20 at (4, 8), blue 24x20 at (40, 20)
    expected = torch.stack([tf(image), tf(image.crop((40, 20, 60, 44))), tf(image.crop((4, 8, 24, 30)))])
    assert torch.allclose(seen[0], expected, atol=1e-6)


class _Overlapping:
    """Three overlapping regions (as SAM gives): left 2/3, right 2/3 and the middle of the frame."""

    def __init__(self, params):
        self.params = params

    def __call__(self, rgb, depth_m, instance):
        from pipeline.encoders.regions import Regions

        masks = np.zeros((3, 12, 16), bool)
        masks[0, :, :10] = True
        masks[1, :, 6:] = True
        masks[2, :, 4:12] = True
        return Regions(masks, rgb.shape[:2])


def test_overlapping_regions_are_added_and_renormalised_in_order():
    from pipeline.encoders.conceptfusion import paint_regions

    masks = _Overlapping(None)(np.zeros((48, 64, 3), np.uint8), None, None).masks.reshape(3, -1)
    masks[:, :16] = False  # the first row is in no region
    fused = torch.nn.functional.normalize(torch.randn(3, 8, dtype=torch.float64), dim=-1)
    got, valid = paint_regions(fused, torch.from_numpy(masks))
    expected = np.zeros((masks.shape[1], 8))
    for i in range(3):  # the reference's loop: add, then renormalise the region's cells
        cells = masks[i]
        acc = expected[cells] + fused[i].numpy()
        expected[cells] = acc / np.linalg.norm(acc, axis=-1, keepdims=True)
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-12)
    assert torch.equal(valid, torch.from_numpy(masks.any(axis=0)))
    three = 16 + 8  # a cell of all three regions: not the plain renormalised sum
    assert not torch.allclose(got[three], torch.nn.functional.normalize(fused.sum(0), dim=0), atol=1e-3)


def test_overlapping_regions_through_the_encoder(gt_encoder):
    from pipeline.encoders.conceptfusion import ConceptFusionEncoder

    enc = ConceptFusionEncoder(gt_encoder.model, _Overlapping(gt_encoder.regions.params), arch=gt_encoder.arch,
                               weights=None, out_size=(12, 16))
    rgb, _, _ = toy_batch(1)
    out = enc.encode_images(rgb)
    f = out.features[0]
    a, b = f[0, 0], f[0, 15]  # only region 0; only region 1
    assert out.valid.all()
    assert torch.allclose(f[0, 4:6], f[0, 4:5].expand(2, -1))  # regions 0 and 2: one feature
    assert not torch.allclose(f[0, 4], a, atol=1e-3) and not torch.allclose(f[0, 10], b, atol=1e-3)
