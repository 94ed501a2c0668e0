"""The ground-truth oracle (a diagnostic): attribute-aware queries, background words, confusion, noise."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.encoders import build_encoder
from pipeline.encoders.base import DenseFeatures, PaletteFeatures
from pipeline.encoders.oracle import OracleEncoder, _words
from pipeline.errors import ConfigError
from tests.pipeline.encoders.conftest import RUNTIME, gt_scene, toy_batch


def oracle(params, **over):
    enc = build_encoder(params.model_copy(update={"oracle": params.oracle.model_copy(update=over)}), "oracle")
    enc.bind_scene(gt_scene())
    return enc


def cell_of(inst: np.ndarray, obj: int) -> tuple[int, int]:
    rows, cols = np.nonzero(inst[0, 2::4, 2::4] == obj)
    return int(rows[0]), int(cols[0])


def test_queries_rank_the_right_instance(params):
    enc = oracle(params)
    rgb, depth, inst = toy_batch(1)
    f = enc.encode_images(rgb, instance=inst).features[0]
    red, blue, bg = f[cell_of(inst, 1)], f[cell_of(inst, 2)], f[0, 0]
    q = enc.encode_text(["a red chair", "the dark blue chair", "chairs", "floor", "wall", "a wooden dining table"])
    assert q[0] @ red > q[0] @ blue and q[1] @ blue > q[1] @ red
    assert q[2] @ red > q[2] @ bg and q[2] @ blue > q[2] @ bg
    assert torch.allclose(q[3], q[4]) and q[3] @ bg == pytest.approx(1.0, abs=1e-5)
    assert (q[5] @ red).abs() < 0.3  # a table query does not match chairs


def test_unknown_query_is_near_orthogonal_and_deterministic(params):
    enc = oracle(params)
    a, b = enc.encode_text(["zxqv", "zxqv"])
    assert torch.equal(a, b)
    assert (a @ enc.encode_text(["chair"])[0]).abs() < 0.4


def test_confusion_and_noise_make_it_imperfect_on_purpose(params):
    rgb, _, inst = toy_batch(2)
    clean = oracle(params).encode_images(rgb, instance=inst).features
    confused = oracle(params, confusion=1.0).encode_images(rgb, instance=inst).features
    noisy = oracle(params, noise_std=0.1).encode_images(rgb, instance=inst).features
    again = oracle(params, noise_std=0.1).encode_images(rgb, instance=inst).features
    r, c = cell_of(inst, 1)
    chair = oracle(params).encode_text(["chair"])[0]
    assert clean[0, r, c] @ chair > 0.8 and confused[0, r, c] @ chair < 0.5  # became the table
    assert torch.equal(noisy, again)  # seeded
    cos = (noisy * clean).sum(-1)
    assert 0.3 < cos.mean() < 0.95


def test_needs_ground_truth_and_instances(params):
    enc = build_encoder(params, "oracle", runtime=RUNTIME)
    rgb, _, inst = toy_batch(1)
    with pytest.raises(ConfigError, match="needs the scene's ground truth"):
        enc.encode_images(rgb, instance=inst)
    enc.bind_scene(gt_scene())
    with pytest.raises(Exception, match="needs instance images"):
        enc.encode_images(rgb)


def _reference(enc: OracleEncoder, instance: np.ndarray) -> np.ndarray:
    """The oracle's definition cell by cell: normalise(compose(class, colours, material)) of the instance at the
    cell centre (background and unknown ids: v('background'))."""
    H, W = instance.shape[1:]
    h, w = enc.out_size
    objs = {o.id: o for o in enc._gt.objects}
    out = np.zeros((len(instance), h, w, enc.dim), np.float32)
    for b in range(len(instance)):
        for r in range(h):
            for c in range(w):
                o = objs.get(int(instance[b, int((r + 0.5) * H / h), int((c + 0.5) * W / w)]))
                v = (enc.word_vector("background") if o is None else
                     enc._compose([" ".join(_words(o.cls))], _words(o.color_name), _words(o.material)))
                out[b, r, c] = v / np.linalg.norm(v)
    return out


@pytest.mark.parametrize("out_size", [(12, 16), (10, 14)])  # whole pixel blocks per cell, and not
def test_cells_are_row_lookups_of_one_table_per_scene(out_size):
    enc = OracleEncoder(out_size=out_size, batch_size=2)
    enc.bind_scene(gt_scene())
    rgb, _, inst = toy_batch(3)
    inst[0, :8, :8] = 77  # an id the scene does not know: background
    out = enc.encode_images(rgb, instance=inst)
    assert isinstance(out, PaletteFeatures) and out.palette.shape == (4, enc.dim)  # background + 3 objects, shared
    np.testing.assert_array_equal(out.features.numpy(), _reference(enc, inst))  # exact, not approximately
    assert out.valid.all() and out.size == out_size
    one = enc.encode_images(rgb[1:2], instance=inst[1:2])
    assert torch.equal(one.features[0], out.features[1])  # independent of batching


def test_confused_frames_stay_row_lookups_and_noise_makes_dense_features():
    rgb, _, inst = toy_batch(3)
    confused = OracleEncoder(out_size=(12, 16), confusion=0.5, batch_size=2)
    confused.bind_scene(gt_scene())
    out = confused.encode_images(rgb, instance=inst)
    assert isinstance(out, PaletteFeatures)
    norms = out.features.norm(dim=-1)
    torch.testing.assert_close(norms, torch.ones_like(norms))
    again = OracleEncoder(out_size=(12, 16), confusion=0.5, batch_size=3)
    again.bind_scene(gt_scene())
    assert torch.equal(again.encode_images(rgb, instance=inst).features, out.features)
    noisy = OracleEncoder(out_size=(12, 16), noise_std=0.1)
    noisy.bind_scene(gt_scene())
    assert type(noisy.encode_images(rgb, instance=inst)) is DenseFeatures
