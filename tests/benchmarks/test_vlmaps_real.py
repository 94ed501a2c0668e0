"""benchmarks/vlmaps_real.py: VLMaps' own builder timed on zipon's frames (a VLMaps checkout is needed for the run;
set VLMAPS_SRC to one, e.g. a clone of github.com/vlmaps/vlmaps, to include it)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from benchmarks.vlmaps_real import load_builder, run_real_loop
from pipeline.geometry import Intrinsics, camera_pose_from_base


def test_a_folder_that_is_no_vlmaps_checkout_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"vlmaps/map/vlmap_builder.py: not found; --vlmaps-src must be"):
        load_builder(tmp_path)


@pytest.mark.skipif(not os.environ.get("VLMAPS_SRC"), reason="set VLMAPS_SRC to a VLMaps checkout")
def test_the_real_loop_runs_on_a_wall_and_counts_its_points():
    h, w, d = 30, 40, 16
    intr = Intrinsics.from_hfov(w, h, 90.0)
    depth = np.full((2, h, w), 2.0, np.float32)  # a wall 2 m ahead of a level camera 1 m up
    poses = np.stack([camera_pose_from_base(0.0, 0.0, 0.0, 1.0), camera_pose_from_base(0.1, 0.0, 0.0, 1.0)])
    rgb = np.zeros((2, h, w, 3), np.uint8)
    feats = np.random.default_rng(0).standard_normal((2, d, h, w)).astype(np.float32)
    t = run_real_loop(Path(os.environ["VLMAPS_SRC"]), depth, poses, intr, rgb, feats, camera_height_m=1.0, pitch=0.0,
                      sample_rate=1, map_height_m=2.0)
    assert (t.frames, t.points) == (2, 2 * h * w)
    # the wall spans heights 1 -+ 1.5 m (rows through pixel centres, VLMaps' depth2pc); VLMaps keeps height cells
    # int(z / 0.05) in [0, 40), i.e. z in (-0.05, 2.0)
    z = 1.0 - (np.arange(h) + 0.5 - intr.cy) / intr.fy * 2.0
    assert t.in_range == 2 * w * int(((z > -0.05) & (z < 2.0)).sum()) and 0 < t.voxels <= t.in_range
    assert 0 < t.loop_cpu_seconds and t.loop_seconds < t.call_seconds
