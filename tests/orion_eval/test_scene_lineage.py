"""The scene handle (pipeline.scene.Scene) the evaluator reads through, and its lineage check."""

import dataclasses
import json
import shutil

import pytest

from pipeline.errors import LineageError, MissingInputError
from pipeline.paths import Workspace
from pipeline.scene import Scene, read_stages
from stages import STAGES


def test_lineage_ok_and_lazy_views(tiny_scene):
    ws, params = tiny_scene
    scene = Scene(ws, params, "tiny", STAGES, check=True)
    shared = scene.check_lineage()
    assert set(shared) == {"recon", "goals"}
    assert scene.grid == scene.recon.grid == scene.goals.grid == scene.routes.grid
    assert scene.gt is not None and len(scene.routes.episodes) > 0
    assert 0.7 < scene.camera_height_m < 1.0  # the simulator's 0.88 m camera


def test_mismatched_reconstruction_is_a_lineage_error(tiny_scene, tmp_path):
    ws, params = tiny_scene
    manifests = tmp_path / "manifests"
    shutil.copytree(ws.manifests_dir, manifests)
    path = manifests / "tiny" / "goals.json"
    doc = json.loads(path.read_text())
    doc["inputs"]["recon"] = "blake2b:" + "0" * 32  # goals built from another reconstruction
    path.write_text(json.dumps(doc))
    other = Workspace(ws.root, ws.data_dir, manifests)
    with pytest.raises(LineageError, match=r"scene tiny: goals was built from recon blake2b:0{32}, but .*reconstruct\.json"):
        Scene(other, params, "tiny", STAGES, check=True)
    (manifests / "tiny" / "routes.json").unlink()
    with pytest.raises(MissingInputError, match="no manifest of stage routes"):
        Scene(other, params, "tiny", STAGES).check_lineage(("routes",))


def test_which_stage_builds_an_artifact_is_read_from_the_registry(tiny_scene, tmp_path):
    ws, params = tiny_scene
    empty = Workspace(ws.root, tmp_path / "data", ws.manifests_dir)
    with pytest.raises(MissingInputError, match=r"scene 'tiny' has no goals yet \(build it: zipon run -s tiny "
                                                r"--stage goals\)"):
        Scene(empty, params, "tiny", STAGES).goals
    renamed = {**STAGES, "goals": dataclasses.replace(STAGES["goals"], name="objectives")}
    with pytest.raises(MissingInputError, match=r"--stage objectives\)"):
        Scene(empty, params, "tiny", renamed).goals
    assert read_stages(STAGES) == ("ingest", "reconstruct", "vlmap", "cfmap", "goals", "routes")
    assert read_stages(renamed)[4] == "objectives"


def test_action_space_comes_from_routes_zarr(tiny_scene):
    ws, params = tiny_scene
    scene = Scene(ws, params, "tiny", STAGES, check=True)
    recorded = scene.routes.attrs
    assert scene.action_space() == (recorded["action_space"]["step_m"], recorded["action_space"]["turn_deg"],
                                   recorded["success_m"]) == (0.25, 15.0, 1.5)


def test_params_disagreeing_with_routes_are_a_lineage_error(tiny_scene):
    ws, params = tiny_scene

    def task(**change):
        return params.model_copy(update={"task": params.task.model_copy(update=change)})

    with pytest.raises(LineageError, match=r"task\.step_m 0\.3 in .*params\.yaml but routes\.zarr of tiny was "
                                           r"built with 0\.25: rebuild with zipon run -s tiny"):
        Scene(ws, task(step_m=0.3), "tiny", STAGES, check=True)
    with pytest.raises(LineageError, match=r"task\.turn_deg 30 in .* built with 15:"):
        Scene(ws, task(turn_deg=30.0), "tiny", STAGES, check=True)
    with pytest.raises(LineageError, match=r"task\.success_m 1 in .* built with 1\.5:"):
        Scene(ws, task(success_m=1.0), "tiny", STAGES, check=True)
    with pytest.raises(LineageError, match=r"task\.hfov_deg 60 in .* built with 90:"):
        Scene(ws, task(hfov_deg=60.0), "tiny", STAGES, check=True)
    Scene(ws, task(success_m=1.0), "tiny", STAGES)  # reading alone is not refused
    Scene(ws, task(clearance_m=0.2), "tiny", STAGES, check=True)  # planning margins are not recorded facts of the routes


def test_goal_regions_are_read_from_goals_zarr(tiny_scene):
    ws, params = tiny_scene
    scene = Scene(ws, params, "tiny", STAGES, check=True)
    assert scene.goals.success_m == scene.routes.success_m == params.task.success_m
    assert any(scene.goals.goal_region(g.id).any() for g in scene.goals.goals)
    assert "region_cells" not in scene.routes.group and scene.routes.attrs["goal_region"]["hfov_deg"] == 90.0


def test_zipon_eval_refuses_another_step_size(tiny_scene, tmp_path, capsys):
    from zipon.cli import main

    ws, _ = tiny_scene
    text = ws.params_path.read_text() + "task: {step_m: 0.3}\n"
    (tmp_path / "params.yaml").write_text(text)
    out = tmp_path / "out"
    code = main(["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), "eval", "-o", str(out), "-m", "cow"])
    assert code == 1
    err = " ".join((capsys.readouterr().err).split())
    assert "task.step_m 0.3 in" in err and "routes.zarr of tiny was built with 0.25: rebuild with zipon run -s tiny" in err
    assert not (out / "results.json").exists()


def test_a_building_gets_a_level_per_floor_and_a_world_with_its_stairs(tiny_house, tiny_scene):
    """A scene of several floors is evaluated (no longer refused): one level per floor (its navigable grid, planners
    and success rule), the world joined at the stairs the reconstruction found; a single floor has one level and a
    world without stairs."""
    from orion_eval.scene import SceneContext

    ws, params = tiny_house
    scene = Scene(ws, params, "house", STAGES, check=True)
    ctx = SceneContext(scene)
    assert ctx.is_building and ctx.floor_ids == [0, 1] and [lv.floor for lv in ctx.levels] == [0, 1]
    for f, lv in enumerate(ctx.levels):
        assert (lv.navigable == scene.recon.floor(f).navigable).all() and lv.success is not None
    assert len(ctx.world.stairs) == len(scene.recon.stairs) >= 1
    way = ctx.world.stairs[0]
    assert way.ends[0].any() and way.ends[1].any() and way.steps >= 2
    # each floor's camera stands about as high above it as the recording's (the simulator's 0.88 m)
    assert all(0.6 < lv.camera_height_m < 1.2 for lv in ctx.levels)
    ws1, params1 = tiny_scene
    flat = SceneContext(Scene(ws1, params1, "tiny", STAGES, check=True))
    assert not flat.is_building and len(flat.levels) == 1 and flat.world.stairs == [] and flat.building is None
    assert flat.planner is flat.levels[0].planner and flat.success is flat.levels[0].success
