"""``zipon view``: a rerun recording of the tiny scene, read back with rerun's RRD reader and counted."""

import gzip
import json

import pytest

from zipon.cli import main


def cli(ws, *args) -> int:
    return main(["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), *args])


@pytest.fixture(scope="module")
def evaluated(built_scene, tmp_path_factory):
    from orion_eval.run import evaluate
    from stages import STAGES

    ws, params = built_scene
    out = tmp_path_factory.mktemp("view_eval")
    evaluate(ws, params, STAGES, out, methods=["orion"], feedback=["mixed"], seeds=[0], progress=False, report=False)
    with gzip.open(out / "episodes" / "tiny.episodes.jsonl.gz", "rt") as f:
        first = json.loads(f.readline())
    return out, first


def test_recording_holds_every_layer_and_the_episode(built_scene, evaluated, tmp_path, capsys):
    from pipeline.goals.store import Goals
    from pipeline.routes.store import Routes
    from pipeline.viewer import recording_contents

    ws, _ = built_scene
    eval_dir, ep = evaluated
    rrd = tmp_path / "tiny.rrd"
    capsys.readouterr()
    assert cli(ws, "view", "tiny", "--out", str(rrd), "--episode", ep["episode"], "--eval", str(eval_dir),
               "-m", "orion", "--max-frames", "12", "--query", "bed") == 0
    assert str(rrd) in capsys.readouterr().out
    got = recording_contents(rrd)
    frames = {p: got[p]["rows"] for p in ("/world/camera", "/world/camera/image", "/world/camera/image/rgb",
                                         "/world/camera/image/depth")}
    assert set(frames.values()) == {12}, frames
    assert {"frame", "capture_time"} <= set(got["/world/camera/image/rgb"]["timelines"])
    assert "Pinhole:image_from_camera" in got["/world/camera/image"]["components"]
    assert "EncodedDepthImage:blob" in got["/world/camera/image/depth"]["components"]
    for static in ("/world", "/world/trajectory", "/world/mesh", "/world/goals", "/world/routes",
                   "/world/routes/starts", "/world/episode/goal", *(f"/world/grids/{g}" for g in
                                                                   ("color", "navigable", "height", "query"))):
        assert got[static]["static"] and got[static]["rows"] == 1, static
    assert "Mesh3D:albedo_texture_buffer" in got["/world/grids/query"]["components"]
    assert "Mesh3D:vertex_colors" in got["/world/mesh"]["components"]
    steps = len(ep["log"]["poses"])
    assert got["/world/episode/robot"]["rows"] == steps and got["/world/episode/path"]["rows"] == steps
    assert got["/world/episode/robot"]["timelines"] == ["log_time", "step"]
    # title + instruction + every Talk turn and reply
    assert got["/dialogue"]["rows"] == 2 + len(ep["log"]["dialogue"])

    import rerun as rr

    import numpy as np

    from pipeline.recon import Recon

    goals, routes = Goals(ws.artifact("goals", "tiny")), Routes(ws.artifact("routes", "tiny"))
    recon = Recon(ws.artifact("recon", "tiny"))
    boxes = strips = mesh_xyz = None
    reader = rr.chunk.RrdReader(rrd)
    assert len(reader.blueprints()) == 1  # the default layout travels with the recording
    for chunk in reader.stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/world/goals":
            boxes = batch.column("Boxes3D:labels")[0].as_py()
        if chunk.entity_path == "/world/routes":
            strips = batch.column("LineStrips3D:strips")[0].as_py()
        if chunk.entity_path == "/world/mesh":
            mesh_xyz = np.asarray(batch.column("Mesh3D:vertex_positions")[0].as_py())
        if chunk.entity_path == "/world/grids/color":
            corners = np.asarray(batch.column("Mesh3D:vertex_positions")[0].as_py())
            fmt = batch.column("Mesh3D:albedo_texture_format")[0].as_py()[0]
            texture = np.asarray(batch.column("Mesh3D:albedo_texture_buffer")[0].as_py()[0], np.uint8)
    assert len(boxes) == sum(len(g.object_keys) for g in goals.goals)
    assert any(goals.goals[0].name in b for b in boxes)
    assert len(strips) == len(routes.episodes)
    # the colour grid's plane: its first corner is the north-west corner of the observed cells and its texture is
    # the recon colour of those cells, row 0 the north edge (so the plane is drawn north-up, like the PNGs)
    seen = np.argwhere(recon.occupancy != 0)
    (r0, c0), (r1, c1) = seen.min(axis=0), seen.max(axis=0) + 1
    g = recon.grid
    nw = g.cell_to_world(np.array([r0, c0])) + np.array([-g.cell_size_m / 2, g.cell_size_m / 2])
    assert np.allclose(corners[0, :2], nw, atol=1e-4) and corners[2, 0] > corners[0, 0]  # east of the west edge
    assert corners[2, 1] < corners[0, 1] and np.allclose(corners[:, 2], recon.floor_z - 0.25)
    assert (fmt["width"], fmt["height"]) == (c1 - c0, r1 - r0)
    assert np.array_equal(texture.reshape(r1 - r0, c1 - c0, 3), recon.color[r0:r1, c0:c1])
    # the ceiling is left out (default --mesh-top 2.2 m) and the mesh simplified (--mesh-voxel 0.04 m)
    full = np.asarray(recon.mesh().vertices)
    assert full[:, 2].max() > recon.floor_z + 2.3 and mesh_xyz[:, 2].max() < recon.floor_z + 2.3
    assert len(mesh_xyz) < 0.8 * len(full)


def test_view_errors_exit_1(built_scene, evaluated, tmp_path, capsys):
    ws, _ = built_scene
    eval_dir, _ = evaluated
    capsys.readouterr()
    assert cli(ws, "view", "nope") == 1
    assert "unknown scene 'nope'" in capsys.readouterr().err
    assert cli(ws, "view", "tiny", "-o", str(tmp_path / "x.png")) == 1
    assert "field --out: got" in capsys.readouterr().err
    assert cli(ws, "view", "tiny", "-o", str(tmp_path / "a.rrd"), "--episode", "x/0", "--eval", str(tmp_path)) == 1
    assert "no evaluation log of scene 'tiny'" in capsys.readouterr().err
    assert cli(ws, "view", "tiny", "-o", str(tmp_path / "a.rrd"), "--episode", "x/0", "--eval", str(eval_dir)) == 1
    assert "no evaluated episode 'x/0'; episodes in the log: [" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*.tmp"))


def test_a_buildings_recording_has_each_floors_grids_and_query_below_that_floor(two_storey_maps, tmp_path):
    import numpy as np
    import rerun as rr

    from pipeline.recon import Recon
    from pipeline.viewer import recording_contents, write_recording

    ws, params, _, _ = two_storey_maps
    rrd = tmp_path / "house.rrd"
    summary = write_recording(ws, params, "house", rrd, query="table", max_frames=6)
    assert summary["grids"] == [f"floor{k}/{g}" for k in (0, 1) for g in ("color", "navigable", "height", "query")]
    got = recording_contents(rrd)
    assert "/world/grids/color" not in got
    recon = Recon(ws.artifact("recon", "house"))
    planes, mesh_xyz = {}, None
    for chunk in rr.chunk.RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path.startswith("/world/grids/floor"):
            planes[chunk.entity_path] = np.asarray(batch.column("Mesh3D:vertex_positions")[0].as_py())
        if chunk.entity_path == "/world/mesh":
            mesh_xyz = np.asarray(batch.column("Mesh3D:vertex_positions")[0].as_py())
    for k, floor in enumerate(recon.floors):  # each floor's layers stacked below that floor
        assert np.allclose(planes[f"/world/grids/floor{k}/color"][:, 2], floor.floor_z_m - 0.25)
        assert np.allclose(planes[f"/world/grids/floor{k}/query"][:, 2], floor.floor_z_m - 1.0)
    # each floor keeps its rooms and loses its ceiling (--mesh-top counts from the floor each surface is on)
    full = np.asarray(recon.mesh().vertices)[:, 2]
    upper = recon.floors[1].floor_z_m
    assert full.max() > upper + 2.3 and upper + 1.0 < mesh_xyz[:, 2].max() < upper + 2.3


def test_a_buildings_goals_and_routes_stand_on_their_floors(built_house, tmp_path):
    import numpy as np
    import rerun as rr

    from pipeline.goals.store import Goals
    from pipeline.recon import Recon
    from pipeline.routes.store import Routes
    from pipeline.viewer import write_recording

    ws, params = built_house
    rrd = tmp_path / "house.rrd"
    write_recording(ws, params, "house", rrd, max_frames=4)
    floor_z = [f.floor_z_m for f in Recon(ws.artifact("recon", "house")).floors]
    goals, routes = Goals(ws.artifact("goals", "house")), Routes(ws.artifact("routes", "house"))
    got = {}
    for chunk in rr.chunk.RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/world/goals":
            got["boxes"] = np.asarray(batch.column("Boxes3D:centers")[0].as_py())
        if chunk.entity_path == "/world/routes":
            got["strips"] = [np.asarray(s) for s in batch.column("LineStrips3D:strips")[0].as_py()]
    keys = [k for g in goals.goals for k in g.object_keys]
    for key, centre in zip(keys, got["boxes"]):  # each box between its floor and that floor's ceiling
        o = goals.objects[key]
        assert centre[2] == pytest.approx(floor_z[o.floor] + sum(o.z_range) / 2, abs=1e-3), key
    for e, strip in zip(routes.episodes, got["strips"]):
        assert len(strip) == len(e.path_xy)
        assert sorted({round(z - 0.05, 2) for z in strip[:, 2]}) == sorted({round(floor_z[f], 2) for f in e.floors})
        assert strip[0, 2] == pytest.approx(floor_z[e.start_floor] + 0.05)


def _house_episode_log(ws, folder, floors_of=None) -> dict:
    """An evaluation log of the house holding one cross-floor route walked as an episode (its poses and the floor of
    each, as the evaluator logs a building's episode); ``floors_of(floors)`` may spoil the floors."""
    from pipeline.routes.store import Routes

    route = next(e for e in Routes(ws.artifact("routes", "house")).episodes if len(e.floors) > 1)
    poses, floors = [], []
    for f, xy in route.legs():
        poses += [[float(x), float(y), 0.0] for x, y in xy]
        floors += [int(f)] * len(xy)
    rec = {"episode": route.id, "method": "orion", "feedback": "mixed", "seed": 0, "goal": route.goal_id,
           "success": True, "end": "success",
           "log": {"poses": poses, "floors": floors_of(floors) if floors_of else floors, "instruction": "find it",
                   "dialogue": []}}
    (folder / "episodes").mkdir(parents=True)
    with gzip.open(folder / "episodes" / "house.episodes.jsonl.gz", "wt") as f:
        f.write(json.dumps(rec) + "\n")
    return rec


def test_a_buildings_episode_is_replayed_on_the_floor_of_each_step(built_house, tmp_path):
    import numpy as np
    import rerun as rr

    from pipeline.recon import Recon
    from pipeline.viewer import write_recording

    ws, params = built_house
    ep = _house_episode_log(ws, tmp_path / "eval")
    rrd = tmp_path / "house.rrd"
    write_recording(ws, params, "house", rrd, max_frames=2, episode=ep["episode"], eval_dir=tmp_path / "eval")
    floor_z = [f.floor_z_m for f in Recon(ws.artifact("recon", "house")).floors]
    zs = []
    for chunk in rr.chunk.RrdReader(rrd).stream():
        if chunk.entity_path == "/world/episode/robot":
            batch = chunk.to_record_batch()
            zs += [p[0][2] for p in batch.column("Points3D:positions").to_pylist() if p]
    assert len(zs) == len(ep["log"]["poses"])
    assert np.allclose(zs, np.asarray(floor_z)[ep["log"]["floors"]] + 0.1, atol=1e-4)


def test_an_episode_log_whose_floors_do_not_fit_the_scene_is_refused(built_house, tmp_path, capsys):
    ws, _ = built_house
    ep = _house_episode_log(ws, tmp_path / "eval", floors_of=lambda floors: [7] * len(floors))
    rrd = tmp_path / "bad.rrd"
    capsys.readouterr()
    assert cli(ws, "view", "house", "--out", str(rrd), "--episode", ep["episode"], "--eval", str(tmp_path / "eval"),
               "--max-frames", "2") == 1
    err = capsys.readouterr().err
    assert "log.floors" in err and "one floor id of 0..1 per pose" in err and ep["episode"] in err
    assert not rrd.exists()
