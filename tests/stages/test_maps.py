"""The vlmap and cfmap stages end to end on the ray-cast box room with the oracle encoder."""

import numpy as np
import pytest

from pipeline.paramsfile import parse_params
from pipeline.stageconfig import digest_value, project
from pipeline.maps.build import build_map
from pipeline.maps.config import MAP_CONFIGS
from pipeline.maps.evaluate import evaluate_map, sample_poses
from pipeline.maps.query import open_query, query_map
from pipeline.maps.store import SemanticMap
from pipeline.paths import Workspace
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from pipeline.engine.runner import StageContext
from stages import STAGES
from stages.cfmap import run as run_cfmap
from stages.vlmap import run as run_vlmap
from tests.fixtures.recon_scenes import write_box_room_frames


def _params(**oracle):
    return parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 100, "cols": 160},
                         "encoders": {"simulated": "oracle", "oracle": {"out_size": [60, 80], **oracle}}})


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("maps")
    frames, gt = write_box_room_frames(tmp / "frames.zarr", n_frames=48)
    params = _params()
    reconstruct(frames, tmp / "recon.zarr", tmp / "recon_mesh.ply", tmp / "recon_points.ply", params.reconstruct,
                params.grid)
    ws = Workspace(root=tmp, data_dir=tmp / "data", manifests_dir=tmp / "manifests")
    out, summaries = tmp / "out", {}
    for stage, run in (("vlmap", run_vlmap), ("cfmap", run_cfmap)):
        outputs = {stage: out / f"{stage}.zarr"}
        ctx = StageContext.build(STAGES[stage], params, "box", ws, {"frames": frames, "recon": tmp / "recon.zarr"},
                                 outputs, show_progress=False)
        summaries[stage] = run(ctx)
    return tmp, out, frames, gt, params, summaries


def test_registered():
    for name in ("vlmap", "cfmap"):
        spec = STAGES[name]
        assert spec.inputs == ("frames", "recon") and spec.outputs == (name,)
        keys = spec.config_class().param_keys(_params(), "box")
        assert "maps.level_height_m" in keys and "encoders.oracle" in keys and "encoders.lseg" not in keys
        assert not any(k.startswith(("query.", "run.", "grid")) for k in keys)


def test_artifacts_describe_themselves(built):
    tmp, out, frames, gt, params, summaries = built
    for name in ("vlmap", "cfmap"):
        m = SemanticMap(out / f"{name}.zarr")
        keys = STAGES[name].config_class().param_keys(params, "box")
        assert m.artifact == name and m.attrs["stage"] == name
        assert m.attrs["params_digest"] == digest_value(project(params, keys))
        assert m.encoder["name"] == "oracle" and m.encoder["diagnostic"] is True and m.dim == 512
        assert m.grid == Recon(tmp / "recon.zarr").grid
        assert m.attrs["frames"] == {"n_frames": 48, "fused": 48, "keyframes_only": False}
        # one floor: the store as before floors existed (version 1, no floors attrs or group), read as one floor
        assert m.attrs["format_version"] == 1 and "floors" not in m.attrs and "floors" not in m.group
        assert len(m.floors) == 1 and "floors" not in summaries[name]
        assert summaries[name]["frames_fused"] == 48 and summaries[name]["cells"] == m.n_cells
    vl, cf = SemanticMap(out / "vlmap.zarr"), SemanticMap(out / "cfmap.zarr")
    assert vl.voxels() is None and len(cf.voxels()) == summaries["cfmap"]["voxels"] > cf.n_cells
    # the same height rule on both maps: the same cells with the same top levels
    assert np.array_equal(vl.cell, cf.cell) and np.array_equal(vl.level, cf.level)
    assert cf.attrs["weighting"] == {"sigma_m": 0.6} and vl.attrs["weighting"] == {"sigma_m": None}


@pytest.mark.parametrize("name", ["vlmap", "cfmap"])
def test_queries_find_every_class(built, name):
    tmp, out, frames, gt, params, _ = built
    mq = open_query(out / f"{name}.zarr", params, recon_path=tmp / "recon.zarr", frames_path=frames)
    poses = sample_poses(Recon(tmp / "recon.zarr").navigable, mq.grid, 6, seed=1)
    figures = evaluate_map(mq, gt, poses)
    print(name, figures)
    assert figures["queries"] == 3 * 7
    assert figures["hit_rate"] >= 0.95
    # 60x80 features of 160x120 frames: the table top (0.75 m, camera 0.88 m) is seen only at grazing angles
    assert all(v["iou"] >= 0.4 for v in figures["per_class"].values()) and figures["mean_iou"] >= 0.55
    r = query_map(out / f"{name}.zarr", tmp / "recon.zarr", "red box", (1.0, 1.0, 0.0), params=params,
                  frames_path=frames)
    top = r.candidates[0]
    assert top.gt_class == "box" and top.gt_instance == 3 and top.approach_xy is not None
    assert r.to_json()["candidates"][0]["gt_class"] == "box"


@pytest.fixture(scope="module")
def picture_room(tmp_path_factory):
    """The box room with a 2 cm picture on the north wall, thinner than a cell and under the wall's top."""
    from pipeline.geometry import Intrinsics
    from pipeline.scene_gt import Box, GTObject
    from pipeline.store import artifact_attrs
    from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames, write_frames

    tmp = tmp_path_factory.mktemp("picture")
    base = box_room_gt()
    picture = GTObject(id=4, cls="picture", room="living_room_1", parts=[Box(min=(2.0, 2.98, 1.0), max=(2.8, 3.0, 1.4))],
                       color_name="yellow", color_rgb=(220, 200, 40), material="paper", size="small")
    gt = base.model_copy(update={"objects": [*base.objects, picture]})
    intr = Intrinsics.from_hfov(160, 120, 90.0)
    poses = box_room_poses(48)
    rgb, depth, inst = render_frames(gt, poses, intr)
    frames = write_frames(tmp / "frames.zarr", gt, rgb, depth, poses, intr, instance=inst)
    params = _params()
    reconstruct(frames, tmp / "recon.zarr", tmp / "recon_mesh.ply", tmp / "recon_points.ply", params.reconstruct,
                params.grid)
    build_map(MAP_CONFIGS["cfmap"].from_params(params, "box"), frames, tmp / "recon.zarr", tmp / "cfmap.zarr",
              artifact_attrs("cfmap", 1, "cfmap", "t"))
    return tmp, frames, gt, params


def test_level_aware_scores_find_a_picture_on_a_wall(picture_room):
    from scipy.ndimage import binary_dilation

    from pipeline.maps.evaluate import class_masks
    from pipeline.maps.levels import LevelScorer
    from pipeline.maps.scoring import logsumexp

    tmp, frames, gt, params = picture_room
    mq = open_query(tmp / "cfmap.zarr", params, recon_path=tmp / "recon.zarr", frames_path=frames)
    m, T = mq.map, mq.temperature
    pic = class_masks(gt, m.grid)["picture"]
    assert pic.any() and not (gt.instance_footprints(m.grid) == 4).any()  # thinner than a cell: no footprint
    near = binary_dilation(pic, iterations=1)[m.cell // m.grid.cols, m.cell % m.grid.cols]
    q = mq.text_features(["picture"])[0]
    bg = mq.text_features(list(params.query.background))
    bg_s = m.dot(bg)
    top_s, top_max, top_lse = m.dot(q), bg_s.max(1), logsumexp(bg_s / T, axis=1)

    def wins(s, bmax, blse):
        return (s > bmax) & (1.0 / (1.0 + np.exp(blse - s / T)) >= params.query.min_probability)

    top = wins(top_s, top_max, top_lse)
    best = wins(*LevelScorer(m).cell_scores(q, bg, T, top_s, top_max, top_lse))
    print("picture cells winning: top-down", int((top & near).sum()), "best level", int((best & near).sum()))
    assert (best & near).sum() >= 8 and (best & near).sum() > (top & near).sum()  # 0.8 m wide: most of 16 cells
    assert not (best & ~near).any()  # and nothing else in the room
    # every other class is still found through its top level
    for cls in ("table", "cabinet", "box"):
        qc = mq.text_features([cls])[0]
        s, bmax, blse = LevelScorer(m).cell_scores(qc, bg, T, m.dot(qc), top_max, top_lse)
        assert wins(s, bmax, blse).sum() >= 0.5 * class_masks(gt, m.grid)[cls].sum()


def test_level_scores_read_block_by_block_are_the_whole_array_s_on_a_built_cfmap(picture_room):
    """The stage's cfmap scored one voxel block at a time gives the bytes the whole-array computation gives, for
    the whole floor and for a region (whose answer is the floor's there); ``query.levels: max`` through MapQuery too."""
    from pipeline.maps.levels import LevelScorer
    from pipeline.maps.scoring import logsumexp
    from pipeline.region import Region, region_window
    from tests.fixtures.level_maps import whole_array_level_scores

    tmp, frames, gt, params = picture_room
    mq = open_query(tmp / "cfmap.zarr", params, recon_path=tmp / "recon.zarr", frames_path=frames)
    m, T = mq.map, mq.temperature
    assert len(m.voxels()) > 3 * 64
    region = Region(1.5, 2.0, 3.5, 3.2)  # the picture and the wall beside it
    win = region_window(m.grid, region)
    idx = m.index_in(win)
    rows = np.sort(idx[idx >= 0])
    bg = mq.text_features(list(params.query.background))
    inf = np.full(m.n_cells, -np.inf, np.float32)
    for text, with_bg in (("picture", True), ("table", True), ("box", True), ("picture", False)):
        q = mq.text_features([text])[0]
        keep = bg[bg @ q <= 0.99] if with_bg else None
        bs = m.dot(keep) if with_bg else None
        top = (m.dot(q), bs.max(1), logsumexp(bs / np.float32(T), axis=1)) if with_bg else (m.dot(q), inf, inf)
        for chunk_rows in (4096, 64):
            want = whole_array_level_scores(m, q, keep, T, *top, chunk_rows=chunk_rows)
            scorer = LevelScorer(m, chunk_rows=chunk_rows)
            for got, w in zip(scorer.cell_scores(q, keep, T, *top), want):
                np.testing.assert_array_equal(got, w)
            for got, w in zip(scorer.cell_scores(q, keep, T, *(a[rows] for a in top), window=win), want):
                np.testing.assert_array_equal(got, w[rows])
    mq.params = params.query.model_copy(update={"levels": "max"})
    mq.levels = "max"
    floor, part = mq.query("picture"), mq.query("picture", region=region)
    assert floor.levels == part.levels == "max" and part.wins.any()
    np.testing.assert_allclose(part.heatmap, floor.heatmap[win.slices], rtol=0, atol=2e-6)
    assert (part.wins == floor.wins[win.slices]).all()


# ----------------------------------------------------------------------------- chunks, workers, appended frames

@pytest.fixture(scope="module")
def growing_room(tmp_path_factory):
    """The box room recorded as 48 frames, then as the same 48 plus a second, shorter tour (72 frames); maps in
    chunks of 16. The 72 frames are reconstructed; the 48-frame recon is that recon cut to its first 48 poses:
    the map stage reuses a fold only when recon keeps its grid and floor (recon places the grid from the surface
    it saw, so more frames may move it a voxel; then the fold is rejected and the map rebuilt)."""
    import shutil

    import zarr

    from pipeline.geometry import Intrinsics
    from tests.fixtures.recon_scenes import box_room_gt, box_room_poses, render_frames, write_frames

    tmp = tmp_path_factory.mktemp("growing")
    params = parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 100, "cols": 160},
                           "reconstruct": {"floor_z_m": 0.0, "voxel_size_m": 0.05}, "maps": {"chunk_frames": 16},
                           "encoders": {"simulated": "oracle", "oracle": {"out_size": [30, 40]}}})
    gt, intr = box_room_gt(), Intrinsics.from_hfov(96, 72, 90.0)
    poses = np.concatenate([box_room_poses(48), box_room_poses(24)])
    rgb, depth, inst = render_frames(gt, poses, intr)
    scenes = {n: (write_frames(tmp / f"frames{n}.zarr", gt, rgb[:n], depth[:n], poses[:n], intr, instance=inst[:n]),
                  tmp / f"recon{n}.zarr") for n in (48, 72)}
    reconstruct(scenes[72][0], scenes[72][1], tmp / "mesh.ply", tmp / "points.ply", params.reconstruct, params.grid)
    shutil.copytree(scenes[72][1], scenes[48][1])
    group = zarr.open_group(scenes[48][1], mode="r+")
    group["pose"].resize((48, 4, 4))
    group["fused"].resize((48,))
    depth[5, 10:20, 10:20] += 100  # a third recording: the second one with one early frame changed
    scenes["changed"] = (write_frames(tmp / "frames_changed.zarr", gt, rgb, depth, poses, intr, instance=inst),
                         scenes[72][1])
    assert np.array_equal(Recon(scenes[48][1]).poses, Recon(scenes[72][1]).poses[:48])
    return tmp, params, scenes


def _scratch_digest(params, stage, frames, recon, out):
    from pipeline.store import artifact_attrs, content_digest

    build_map(MAP_CONFIGS[stage].from_params(params, "box"), frames, recon, out, artifact_attrs(stage, 1, stage, "t"))
    return content_digest(out)


def _stage_run(params, stage, ws, frames, recon, out):
    """The stage's run() in a workspace (its fold cache at ``ws.fold``); (summary, content digest of the map,
    the stage's log)."""
    from pipeline.store import content_digest

    ctx = StageContext.build(STAGES[stage], params, "box", ws, {"frames": frames, "recon": recon}, {stage: out},
                             show_progress=False)
    return {"vlmap": run_vlmap, "cfmap": run_cfmap}[stage](ctx), content_digest(out), ctx.messages


def test_chunks_on_two_dask_workers_give_the_maps_one_process_gives(growing_room):
    import functools

    from distributed import Client, LocalCluster, get_task_stream

    from pipeline.engine.runner import ordered_tasks
    from pipeline.store import artifact_attrs, content_digest

    tmp, params, scenes = growing_room
    frames, recon = scenes[72]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        for stage in ("vlmap", "cfmap"):
            serial = _scratch_digest(params, stage, frames, recon, tmp / f"serial-{stage}.zarr")
            config = MAP_CONFIGS[stage].from_params(params, "box")
            with get_task_stream(client) as tasks:  # build_map runs in a worker; its chunks become tasks
                summary = client.submit(build_map, config, frames, recon, tmp / f"two-{stage}.zarr",
                                        artifact_attrs(stage, 1, stage, "t"),
                                        map_ordered=functools.partial(ordered_tasks, name=f"chunk-{stage}")).result()
            assert summary["chunks"] == 5 and summary["frames_fused"] == 72
            assert len({t["worker"] for t in tasks.data if t["key"].startswith(f"chunk-{stage}-")}) == 2  # both ran chunks
            assert content_digest(tmp / f"two-{stage}.zarr") == serial


@pytest.mark.parametrize("stage", ["vlmap", "cfmap"])
def test_appended_frames_fuse_only_the_new_chunks_and_give_the_map_built_from_scratch(growing_room, stage):
    tmp, params, scenes = growing_room
    ws = Workspace(root=tmp, data_dir=tmp / f"data-{stage}", manifests_dir=tmp / "manifests")
    no_fold = params.model_copy(update={"run": params.run.model_copy(update={"map_fold_cache": False})})
    scratch_ws = Workspace(root=tmp, data_dir=tmp / f"scratch-{stage}", manifests_dir=tmp / "manifests")
    runs = iter(range(100))

    def run(scene, p=params, w=ws):
        return _stage_run(p, stage, w, *scenes[scene], w.data_dir / f"run{next(runs)}" / f"{stage}.zarr")

    first, _, _ = run(48)
    assert (first["chunks"], first["chunks_reused"], first["frames_reused"]) == (3, 0, 0)
    assert ws.fold("box", stage).is_dir()
    grown, digest, log = run(72)  # 48 frames + 24 appended
    assert (grown["chunks"], grown["chunks_reused"], grown["frames_reused"], grown["frames_processed"]) == (5, 3, 48, 24)
    assert f"reusing the fold of frames 0-47 (.{stage}.fold); fusing 24" in log
    scratch, scratch_digest, _ = run(72, no_fold, scratch_ws)
    assert scratch["chunks_reused"] == 0 and not scratch_ws.fold("box", stage).exists()
    assert digest == scratch_digest
    again, digest, _ = run(72)  # the fold now holds 4 complete chunks; the last 8 frames are recomputed
    assert (again["chunks_reused"], again["frames_processed"]) == (4, 8) and digest == scratch_digest
    # an early frame changed: its chunk's digest differs, so nothing is reused
    changed, digest, log = run("changed")
    assert changed["chunks_reused"] == 0 and changed["frames_processed"] == 72 and digest != scratch_digest
    assert any("chunk 0 (frames 0-15) changed" in line for line in log)
