"""Region generators: colour + depth cuts, ground-truth masks, the guarded SAM import."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from pipeline.encoder_params.conceptfusion import RegionParams
from pipeline.encoders.regions import REGION_GENERATORS, Regions, build_region_generator
from pipeline.errors import ConfigError, InputDataError
from tests.pipeline.encoders.conftest import toy_batch


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def test_rgbd_regions_find_the_coloured_objects():
    rgb, depth, inst = toy_batch(1)
    regions = build_region_generator(RegionParams(work_height=48))(rgb[0], depth[0], None)
    assert regions.masks.shape[1:] == (48, 64)
    for obj in (1, 2):
        assert max(iou(m, inst[0] == obj) for m in regions.masks) > 0.8


def test_depth_discontinuity_cuts_a_uniformly_coloured_frame():
    rgb = np.full((48, 64, 3), 128, np.uint8)
    depth = np.full((48, 64), 4.0, np.float32)
    depth[:, 32:] = 1.0  # same colour, a step of 3 m
    with_depth = build_region_generator(RegionParams(work_height=48, depth_weight=0.5))(rgb, depth, None)
    colour_only = build_region_generator(RegionParams(work_height=48, depth_weight=0.0))(rgb, depth, None)
    assert len(colour_only) == 1
    assert len(with_depth) == 2 and max(iou(m, depth > 2) for m in with_depth.masks) > 0.9


def test_gt_regions_are_the_instances_and_need_instance_images():
    rgb, depth, inst = toy_batch(1)
    gen = build_region_generator(RegionParams(generator="gt", work_height=48, gt_background=False))
    regions = gen(rgb[0], depth[0], inst[0])
    assert len(regions) == 2
    assert sorted(iou(m, inst[0] == k) for m in regions.masks for k in (1, 2))[-2:] == [1.0, 1.0]
    with pytest.raises(InputDataError, match="needs instance images"):
        gen(rgb[0], depth[0], None)


def test_boxes_and_resampling_use_the_pixel_corner_grid():
    masks = np.zeros((1, 12, 16), bool)
    masks[0, 3:6, 4:8] = True
    r = Regions(masks, (48, 64))
    np.testing.assert_allclose(r.boxes_px(), [[16, 12, 32, 24]])
    assert r.resampled((24, 32))[0].sum() == masks.sum() * 4


@pytest.mark.skipif(importlib.util.find_spec("segment_anything") is not None, reason="segment_anything installed")
def test_sam_chosen_without_the_package_is_a_clear_error():
    assert "sam" in REGION_GENERATORS
    with pytest.raises(ConfigError, match="'sam' but the segment_anything package is not installed"):
        build_region_generator(RegionParams(generator="sam", sam_checkpoint="/nowhere/sam.pth"))
