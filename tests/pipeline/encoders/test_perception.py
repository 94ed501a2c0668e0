"""The simulated perception models: real CLIP text space, per-profile error structure, seeding, errors.

(The shared encoder contract runs on them too: tests/pipeline/encoders/test_base.py.)
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.config import EncodersParams
from pipeline.encoders import build_encoder, encoder_choice
import pipeline
from pipeline.encoders.perception_text import (EMBEDDINGS_FILE, NAMES_FILE, SIM_CLASS_LVIS, load_text_space,
                                               resolve_embeddings, shipped_embeddings)
from pipeline.errors import ConfigError, InputDataError, MissingInputError
from pipeline.scene_gt import GTScene
from pipeline.sim.catalog import TEMPLATES
from tests.pipeline.encoders.conftest import RUNTIME, gt_scene

H, W = 60, 80


@pytest.fixture(scope="module")
def space():
    return load_text_space(resolve_embeddings(None, "test"))


def scene(objects) -> GTScene:
    """A GT scene of ``objects``: (id, cls, colour, material)."""
    return GTScene.model_validate({
        "name": "perception", "seed": 0, "wall_height_m": 2.5, "rooms": [], "walls": [],
        "objects": [{"id": i, "cls": c, "room": "r", "parts": [{"min": (i, 0, 0), "max": (i + 0.5, 0.5, 0.8)}],
                     "color_name": col, "color_rgb": (1, 2, 3), "material": mat, "size": "big"}
                    for i, c, col, mat in objects],
    })


def encoder(name: str, **settings):
    enc = build_encoder(EncodersParams.model_validate({name: {"out_size": (H, W), **settings}}), name)
    return enc


def frames(masks: dict[int, tuple[slice, slice]], n: int = 1) -> np.ndarray:
    inst = np.zeros((n, H, W), np.uint16)
    for i, (r, c) in masks.items():
        inst[:, r, c] = i
    return inst


def scores(enc, inst, texts):
    rgb = np.zeros(inst.shape + (3,), np.uint8)
    out = enc.encode_images(rgb, instance=inst)
    return torch.einsum("bhwd,td->bhwt", out.features, enc.encode_text(texts)).numpy(), out


# ----------------------------------------------------------------------------- text space

def test_text_space_follows_clip_similarities(space):
    v = {t: space.encode(t) for t in ("chair", "armchair", "toilet", "desk", "table", "floor", "red chair",
                                      "Alice's red chair", "a red chair made of wood", "zorblax")}
    assert v["chair"] @ v["armchair"] > 0.95 > v["chair"] @ v["toilet"] + 0.05
    assert v["desk"] @ v["table"] > 0.9
    assert v["red chair"] @ v["Alice's red chair"] == pytest.approx(1.0)  # names carry nothing
    assert 0.85 < v["chair"] @ v["red chair"] < 0.95
    assert v["red chair"] @ v["a red chair made of wood"] > v["chair"] @ v["a red chair made of wood"]
    assert 0.6 < v["chair"] @ v["floor"] < 0.85  # background words behave like another class
    assert abs(v["zorblax"] @ v["chair"]) < 0.2  # unknown text: a direction of its own


def test_every_simulated_class_has_a_clip_feature(space):
    for t in TEMPLATES.values():
        assert t.cls in SIM_CLASS_LVIS
        assert space.class_vector(t.cls).shape == (space.dim,)
    # a class with no single LVIS name is the mean of its rows: near both
    assert space.class_vector("nightstand") @ space.class_vector("cabinet") > 0.9


def test_the_default_embeddings_ship_with_zipon():
    folder = Path(resolve_embeddings(None, "encoders.simulated_lseg.embeddings"))
    assert folder == shipped_embeddings().resolve() and folder.parent.parent == Path(pipeline.__file__).parent
    space = load_text_space(str(folder))
    assert space.rows.shape == (1203, 512) and space.names[0] == "aerosol_can"
    assert (folder / "README.md").is_file() and (folder / "LICENSE-Apache-2.0").is_file()


def test_missing_embeddings_name_the_param(tmp_path):
    with pytest.raises(MissingInputError, match=r"encoders\.simulated_lseg\.embeddings: no "
                                                r"lvis_v1_clip_vitb32_a\+cname\.npy in " + re.escape(str(tmp_path))):
        build_encoder(EncodersParams.model_validate({"simulated_lseg": {"embeddings": str(tmp_path)}}),
                      "simulated_lseg")


def _embeddings_folder(tmp_path, array=None, raw: bytes | None = None):
    """A copy of the shipped names with ``array`` (or ``raw`` bytes) as the embeddings file."""
    folder = tmp_path / "emb"
    folder.mkdir()
    (folder / NAMES_FILE).write_bytes((shipped_embeddings() / NAMES_FILE).read_bytes())
    if raw is not None:
        (folder / EMBEDDINGS_FILE).write_bytes(raw)
    else:
        np.save(folder / EMBEDDINGS_FILE, array)
    return folder


@pytest.mark.parametrize("array, raw, expect", [
    (np.ones((10, 512), np.float16), None, r"holds a float16 array of shape \(10, 512\); expected a float array "
                                           r"\(1203, D\): one row per name line of .*lvis_v1_names\.txt"),
    (np.ones(1203, np.float32), None, r"shape \(1203,\)"),
    (np.ones((1203, 512), np.int64), None, r"holds a int64 array"),
    (np.zeros((1203, 512), np.float32), None, r"row 0 is zero or not finite"),
    (None, b"not an npy file at all", r"cannot be read \(ValueError"),
])
def test_wrong_embeddings_are_one_clear_error(tmp_path, array, raw, expect):
    folder = _embeddings_folder(tmp_path, array, raw)
    with pytest.raises(InputDataError, match=r"^encoders\.simulated_cf\.embeddings: .*" + expect):
        build_encoder(EncodersParams.model_validate({"simulated_cf": {"embeddings": str(folder)}}), "simulated_cf")


@pytest.mark.parametrize("broken", ["missing", "shape"])
def test_cli_names_the_key_and_the_file_and_exits_1(tmp_path, capsys, broken):
    from zipon.cli import main

    folder = tmp_path / "nowhere" if broken == "missing" else _embeddings_folder(tmp_path, np.ones((3, 8), np.float32))
    (tmp_path / "params.yaml").write_text("scenes: {a: {source: simulate}}\n"
                                          f"encoders: {{simulated_lseg: {{embeddings: '{folder}'}}}}\n")
    code = main(["-p", str(tmp_path / "params.yaml"), "encoders", "check", "--which", "simulated_lseg"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines[0].startswith("error: encoders.simulated_lseg.embeddings: ")
    assert str(folder) in " ".join(err.split()), err


def test_perception_choice_gives_each_map_its_model():
    p = EncodersParams.model_validate({"simulated": "perception"})
    assert encoder_choice(p, "vlmap", simulated=True) == "simulated_lseg"
    assert encoder_choice(p, "cfmap", simulated=True) == "simulated_cf"
    assert encoder_choice(p, "vlmap", simulated=False) == "lseg"
    ident = build_encoder(p, "cfmap", simulated=True, runtime=RUNTIME).identity()
    assert ident["profile"] == "conceptfusion" and ident["diagnostic"] is False
    assert "simulated ConceptFusion-like" in ident["kind"] and "not a trained model" in ident["kind"]


def test_check_runs_the_models_on_a_synthetic_scene():
    from pipeline.encoders import check_encoder

    p = EncodersParams.model_validate({"simulated": "perception"})
    for which, name in (("vlmap", "simulated_lseg"), ("cfmap", "simulated_cf")):
        report = check_encoder(p, which, simulated=True)
        assert report["identity"]["name"] == name and report["feature_grid"] == [120, 160]
        assert report["text_shape"] == [1, 512] and report["valid_fraction"] == 1.0


# ----------------------------------------------------------------------------- both models

@pytest.mark.parametrize("name", ["simulated_lseg", "simulated_cf"])
def test_needs_ground_truth_and_instances(name):
    enc = encoder(name)
    rgb = np.zeros((1, H, W, 3), np.uint8)
    with pytest.raises(ConfigError, match="SIMULATED scenes"):
        enc.encode_images(rgb, instance=np.zeros((1, H, W), np.uint16))
    enc.bind_scene(gt_scene())
    with pytest.raises(InputDataError, match="field instance"):
        enc.encode_images(rgb)


@pytest.mark.parametrize("name", ["simulated_lseg", "simulated_cf"])
def test_seeded_and_object_recognised_without_confusion(name):
    inst = frames({1: (slice(10, 50), slice(10, 40)), 3: (slice(20, 50), slice(50, 75))}, n=2)
    inst[1, 0, 0] = 1  # a different frame
    enc = encoder(name, object_confusion=0.0, frame_confusion=0.0)
    enc.bind_scene(gt_scene())
    s, out = scores(enc, inst, ["chair", "dining table", "floor"])
    again = encoder(name, object_confusion=0.0, frame_confusion=0.0)
    again.bind_scene(gt_scene())
    assert torch.equal(again.encode_images(np.zeros(inst.shape + (3,), np.uint8), instance=inst).features,
                       out.features)
    assert s[0, 30, 25].argmax() == 0 and s[0, 35, 62].argmax() == 1  # the chair and the table
    other = encoder(name, seed=5, object_confusion=0.0, frame_confusion=0.0)
    other.bind_scene(gt_scene())
    assert not torch.equal(other.encode_images(np.zeros(inst.shape + (3,), np.uint8), instance=inst).features,
                           out.features)


@pytest.mark.parametrize("name", ["simulated_lseg", "simulated_cf"])
def test_confusions_go_to_clip_similar_classes(name, space):
    classes = ["chair", "table", "cabinet", "bed", "toilet", "lamp", "desk", "couch"]
    gt = scene([(i + 1, c, "grey", "wood") for i, c in enumerate(classes)])
    inst = np.zeros((1, H, W), np.uint16)
    for i in range(len(classes)):
        inst[0, 5:55, i * 10 : i * 10 + 9] = i + 1
    enc = encoder(name, object_confusion=1.0, object_confusion_strength=(1.0, 1.0), frame_confusion=0.0,
                  attribute_weight=0.0, background_noise=0.0, object_noise=0.0,
                  **({"merge_probability": 0.0} if name == "simulated_cf" else {"blur_cells": 0.0}))
    enc.bind_scene(gt)
    out = enc.encode_images(np.zeros((1, H, W, 3), np.uint8), instance=inst).features[0].numpy()
    own = np.stack([space.class_vector(c) for c in classes])
    centre = out[30, [i * 10 + 4 for i in range(len(classes))]]  # (8,D)
    cos_own = (centre * own).sum(1)
    assert (cos_own < 0.99).all()  # every object took another class of the scene ...
    pair = own @ own.T
    random_other = (pair.sum() - np.trace(pair)) / (len(classes) * (len(classes) - 1))
    assert np.mean(cos_own) > random_other + 0.03  # ... mostly a CLIP neighbour, not a random one


# ----------------------------------------------------------------------------- LSeg-like

def test_lseg_bleeds_at_boundaries_and_washes_out_thin_objects():
    gt = scene([(1, "chair", "grey", "wood"), (2, "lamp", "grey", "metal")])
    inst = frames({1: (slice(10, 50), slice(10, 40)), 2: (slice(5, 55), slice(60, 61))})  # a 1-cell-thin lamp
    kw = dict(object_confusion=0.0, frame_confusion=0.0, background_noise=0.0, object_noise=0.0)
    sharp, blurred = encoder("simulated_lseg", blur_cells=0.0, **kw), encoder("simulated_lseg", blur_cells=2.5, **kw)
    for e in (sharp, blurred):
        e.bind_scene(gt)
    s0, _ = scores(sharp, inst, ["chair", "lamp", "floor"])
    s1, _ = scores(blurred, inst, ["chair", "lamp", "floor"])
    # two cells outside the chair: background without blur, chair-like with it
    assert s0[0, 30, 41].argmax() == 2 and s1[0, 30, 41, 0] > s0[0, 30, 41, 0] + 0.02
    assert s0[0, 30, 60].argmax() == 1 and s1[0, 30, 60].argmax() != 1  # the thin lamp is lost in the background
    assert s1[0, 30, 25].argmax() == 0  # the chair's interior stays a chair


def test_lseg_background_is_low_confidence():
    gt = scene([(1, "chair", "grey", "wood"), (2, "bed", "grey", "wood"), (3, "toilet", "white", "ceramic")])
    inst = frames({1: (slice(0, 10), slice(0, 10)), 2: (slice(50, 60), slice(70, 80)), 3: (slice(0, 5), slice(75, 80))})
    quiet = encoder("simulated_lseg", background_noise=0.0, object_noise=0.0)
    noisy = encoder("simulated_lseg", background_noise=1.5, object_noise=0.0)
    for e in (quiet, noisy):
        e.bind_scene(gt)
    bg = (slice(15, 45), slice(15, 65))
    s0, _ = scores(quiet, inst, ["chair", "bed", "toilet", "floor"])
    s1, _ = scores(noisy, inst, ["chair", "bed", "toilet", "floor"])
    assert (s0[0][bg].argmax(-1) == 3).all()
    wrong = (s1[0][bg].argmax(-1) != 3).mean()
    assert 0.05 < wrong < 0.95  # smooth patches of false class responses on the floor


# ----------------------------------------------------------------------------- ConceptFusion-like

def test_cf_regions_are_sharp_whole_objects_and_merge():
    gt = scene([(1, "chair", "grey", "wood"), (2, "table", "brown", "wood"), (3, "lamp", "red", "metal")])
    inst = frames({1: (slice(10, 50), slice(10, 30)), 2: (slice(10, 50), slice(30, 60)),
                   3: (slice(5, 7), slice(70, 72))})  # the lamp is 4 of 4800 cells: below min_region_frac
    kw = dict(object_confusion=0.0, frame_confusion=0.0, background_noise=0.0, object_noise=0.0)
    apart = encoder("simulated_cf", merge_probability=0.0, **kw)
    merged = encoder("simulated_cf", merge_probability=1.0, **kw)
    for e in (apart, merged):
        e.bind_scene(gt)
    _, a = scores(apart, inst, ["chair"])
    _, m = scores(merged, inst, ["chair"])
    fa, fm = a.features[0], m.features[0]
    assert torch.equal(fa[10, 10], fa[49, 29]) and not torch.equal(fa[30, 29], fa[30, 30])  # sharp, per region
    assert torch.equal(fm[30, 29], fm[30, 30])  # touching objects merged: one feature
    assert torch.equal(fa[6, 71], fa[0, 0])  # the too-small lamp is part of the background region


def test_cf_mixes_the_global_context():
    gt = scene([(1, "chair", "grey", "wood"), (2, "bed", "red", "fabric"), (3, "toilet", "red", "fabric")])
    enc = encoder("simulated_cf", object_confusion=0.0, frame_confusion=0.0, background_noise=0.0,
                  object_noise=0.0, merge_probability=0.0)
    enc.bind_scene(gt)
    with_bed = frames({1: (slice(20, 30), slice(10, 20)), 2: (slice(0, 60), slice(30, 80))})
    with_toilet = frames({1: (slice(20, 30), slice(10, 20)), 3: (slice(0, 60), slice(30, 80))})
    s_bed, _ = scores(enc, with_bed, ["chair", "bed", "toilet"])
    s_toilet, _ = scores(enc, with_toilet, ["chair", "bed", "toilet"])
    # the same chair leans toward whatever dominates its frame, and stays a chair
    assert s_bed[0, 25, 15, 1] - s_toilet[0, 25, 15, 1] > 0.02
    assert s_toilet[0, 25, 15, 2] - s_bed[0, 25, 15, 2] > 0.02
    assert s_bed[0, 25, 15].argmax() == 0 and s_toilet[0, 25, 15].argmax() == 0


def test_lseg_keeps_attributes_weakly_and_cf_reads_them_off_the_whole_box():
    gt = scene([(1, "chair", "red", "fabric"), (2, "chair", "blue", "fabric")])
    apart = frames({1: (slice(10, 50), slice(5, 35)), 2: (slice(10, 50), slice(45, 75))})
    kw = dict(object_confusion=0.0, frame_confusion=0.0, background_noise=0.0, object_noise=0.0)
    gaps = {}
    for name, misread in (("simulated_lseg", 0.0), ("simulated_cf", 0.0), ("simulated_cf", 1.0)):
        e = encoder(name, attribute_confusion=misread, **kw,
                    **({"merge_probability": 0.0} if name == "simulated_cf" else {}))
        e.bind_scene(gt)
        s, _ = scores(e, apart, ["red chair"])
        gaps[name, misread] = s[0, 30, 20, 0] - s[0, 30, 60, 0]
    # LSeg's pixel features are trained toward category labels: colour is a faint trace; a CLIP crop sees it
    assert gaps["simulated_cf", 0.0] > 2 * gaps["simulated_lseg", 0.0] > 0
    # colours always misread: the red chair is no longer told from the blue one
    assert abs(gaps["simulated_cf", 1.0]) < 0.5 * gaps["simulated_cf", 0.0]
    # the red chair drawn as a thin L around the blue one: its box crop is mostly blue chair, and CLIP reports
    # the crop's colours, not the region's own (the blue chair's box holds only itself)
    around = np.zeros((1, H, W), np.uint16)
    around[0, 10:50, 5:8] = 1
    around[0, 47:50, 5:60] = 1
    around[0, 12:44, 12:58] = 2
    e = encoder("simulated_cf", attribute_confusion=0.0, merge_probability=0.0, **kw)
    e.bind_scene(gt)
    s_apart, _ = scores(e, apart, ["red chair", "blue chair"])
    s_around, _ = scores(e, around, ["red chair", "blue chair"])
    red_apart, red_l, blue = s_apart[0, 30, 20], s_around[0, 30, 6], s_around[0, 30, 30]
    assert red_l[0] - blue[0] < 0.5 * gaps["simulated_cf", 0.0]  # red hardly sets it apart any more ...
    assert red_l[0] - red_l[1] < 0.5 * (red_apart[0] - red_apart[1])  # ... it reads about as blue as red


def test_cf_pixels_carry_the_coarser_mask_of_their_touching_neighbours():
    gt = scene([(1, "chair", "red", "fabric"), (2, "chair", "blue", "fabric")])
    apart = frames({1: (slice(10, 50), slice(5, 35)), 2: (slice(10, 50), slice(45, 75))})
    touching = frames({1: (slice(10, 50), slice(10, 40)), 2: (slice(10, 50), slice(40, 70))})
    e = encoder("simulated_cf", attribute_confusion=0.0, object_confusion=0.0, frame_confusion=0.0,
                background_noise=0.0, object_noise=0.0, merge_probability=0.0)
    e.bind_scene(gt)
    s_apart, _ = scores(e, apart, ["red chair"])
    s_touch, feats = scores(e, touching, ["red chair"])
    gap_apart = s_apart[0, 30, 20, 0] - s_apart[0, 30, 60, 0]
    gap_touch = s_touch[0, 30, 25, 0] - s_touch[0, 30, 55, 0]
    # SAM also returns the mask of both chairs; ConceptFusion adds its feature to both: the colours blur together
    assert 0 < gap_touch < 0.8 * gap_apart, (gap_touch, gap_apart)
    f = feats.features[0]
    assert not torch.equal(f[30, 25], f[30, 55])  # still two regions (no merge): each keeps its own mask
