"""navchat goal files as navchat reads them: its grid frame, base fallback, names with the class, coverage of
the observed map, and a lossless export. The files here are written by the test (navchat's layout)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import InputDataError
from pipeline.geometry import GridSpec, camera_pose_from_base
from pipeline.goals.navchat import (NavchatFrame, check_navchat_coverage, export_navchat, import_navchat,
                                    navchat_name, write_navchat)
from pipeline.goals.schema import RoomEntry

T_FIRST = camera_pose_from_base(2.0, -1.0, np.pi / 2, 0.88)  # first pose at (2, -1), facing +y (north)


def _contour(c0, r0, w, h):
    return [[[c0, r0]], [[c0 + w, r0]], [[c0 + w, r0 + h]], [[c0, r0 + h]]]


def write_scene(folder: Path) -> Path:
    """A navchat-layout goal folder: three objects, four goals (one only in final.json), rooms with owners."""
    objects = {
        "bed_0": {"name": "bed", "center": [310, 280], "mass": 200.0, "contour": _contour(300, 270, 20, 20)},
        "chair_0": {"name": "chair", "center": [285, 305], "mass": 25.0, "contour": _contour(282, 302, 5, 5)},
        "chair_1": {"name": "chair", "center": [295, 320], "mass": 25.0, "contour": _contour(292, 317, 5, 5)},
    }
    final = {
        "room_info": {"bedroom": "Alice|shared", "living room": "shared"},
        "bed_0": {"base": json.dumps({"center": [310, 280], "mass": 200.0}), "nearby_obj": "chair_0",
                  "object_desc": "with grey dotted white sheet|has a pillow", "attr": "bought from IKEA",
                  "room_id": "bedroom_1", "explain": "a furniture for sleeping.", "type": "big"},
        "chair_0": {"base": json.dumps({"center": [285, 305], "mass": 25.0}), "nearby_obj": "",
                    "object_desc": "red wooden chair", "attr": "Amazon basics", "room_id": "living room_1",
                    "explain": "a seat", "type": "ambiguous", "same_goal": "chair_0|chair_1|ghost_9"},
        "chair_1": {"base": json.dumps({"center": [295, 320], "mass": 25.0}), "nearby_obj": "",
                    "object_desc": "blue chair", "attr": None, "room_id": "bedroom_2", "explain": "",
                    "type": "small", "same_goal": "chair_1"},
        "towel_0": {"base": json.dumps({"center": [330, 300], "mass": 3.5}), "nearby_obj": "",
                    "object_desc": "blue towel hanging on the bar", "attr": None, "room_id": "bedroom_2",
                    "explain": "a piece of cloth", "type": "small"},
    }
    folder.mkdir(parents=True)
    (folder / "objects.json").write_text(json.dumps(objects))
    (folder / "final.json").write_text(json.dumps(final, indent=2))
    return folder


@pytest.mark.parametrize("rounding", ["trunc", "round"])
def test_frame_is_anchored_at_the_first_pose(rounding):
    f = NavchatFrame.from_first_pose(T_FIRST, rounding=rounding)
    # facing north: right is east (+x), backward is south (-y)
    assert f.to_cells([2.0, -1.0]).tolist() == [300, 300]
    assert f.to_cells([3.0, -1.0]).tolist() == [320, 300]
    assert f.to_cells([2.0, -2.0]).tolist() == [300, 320]
    trunc = rounding == "trunc"
    assert f.to_cells([2.04, -1.0]).tolist() == [300 if trunc else 301, 300]  # int(0.8) = 0, round(0.8) = 1
    assert f.to_cells([1.94, -1.0]).tolist() == [299, 300]  # int(-1.2) = -1
    cells = np.stack(np.meshgrid(np.arange(280, 321), np.arange(290, 311)), -1).reshape(-1, 2)
    assert np.array_equal(f.to_cells(f.to_world(cells)), cells)


def test_grid_origin_reads_cells_on_the_recon_grid():
    grid = GridSpec(100, 100, 0.05, (0.0, 5.0))
    f = NavchatFrame.from_grid(grid)
    assert np.allclose(f.to_world([10, 20]), grid.cell_to_world([20, 10]))  # navchat (col, row)


def test_import_as_navchat_reads_it(tmp_path):
    logs = []
    objset, doc = import_navchat(write_scene(tmp_path / "s"), NavchatFrame.from_first_pose(T_FIRST), "s",
                                 log=logs.append)
    by_key = objset.by_key()
    assert set(by_key) == {"bed_0", "chair_0", "chair_1", "towel_0"}
    # towel_0 is not in objects.json: placed at its base like navchat's loader (class from the key), reported
    towel = by_key["towel_0"]
    assert towel.cls == "towel"
    assert np.allclose(towel.mass_center, NavchatFrame.from_first_pose(T_FIRST).to_world([330, 300]))
    assert any("['towel_0'] are not in objects.json" in m for m in logs)
    assert any("same_goal members ['ghost_9'] are not objects" in m for m in logs)
    names = {g.id: g.name for g in doc.goals}
    assert names == {"bed_0": "Alice's bed", "chair_0": "the Amazon basics chair", "chair_1": "the chair",
                     "towel_0": "the towel"}
    goals = {g.id: g for g in doc.goals}
    assert goals["chair_0"].objects == ["chair_0", "chair_1"]
    assert doc.rooms["bedroom_1"].owners == ["Alice"] and doc.rooms["bedroom_2"].owners == []  # "Alice|shared"
    assert goals["bed_0"].feedback.descriptive == "with grey dotted white sheet. has a pillow."


def test_names_keep_the_class():
    alice = RoomEntry(type="bedroom", owners=["Alice"], name="Alice's bedroom")
    assert navchat_name("chair", None, "Amazon basics") == "the Amazon basics chair"
    assert navchat_name("bed", None, "bought from IKEA") == "the bed bought from IKEA"
    assert navchat_name("chair", None, "Maiden Home chair") == "the Maiden Home chair"
    assert navchat_name("bookshelf", None, "Alice's bookshelf") == "Alice's bookshelf"
    assert navchat_name("bed", alice, "bought from IKEA") == "Alice's bed"
    assert navchat_name("table", None, None) == "the table"


def test_export_is_lossless_and_changes_only_edits(tmp_path):
    src = write_scene(tmp_path / "s")
    frame = NavchatFrame.from_first_pose(T_FIRST)
    objset, doc = import_navchat(src, frame, "s")
    write_navchat(tmp_path / "out", *export_navchat(objset, doc, frame, source=src))
    for name in ("objects.json", "final.json"):
        assert (tmp_path / "out" / name).read_bytes() == (src / name).read_bytes()
    # without the source, the cells are still reproduced from world positions
    objects_json, _ = export_navchat(objset, doc, frame)
    shipped = json.loads((src / "objects.json").read_text())
    assert all(objects_json[k]["contour"] == shipped[k]["contour"] for k in shipped)
    # an edited goal changes only the edited fields; attr, explain, nearby_obj, base stay as shipped
    goals = [g.model_copy(update={"name": "my reading chair", "type": "small"}) if g.id == "chair_0" else g
             for g in doc.goals]
    _, final = export_navchat(objset, doc.model_copy(update={"goals": goals}), frame, source=src)
    shipped_final = json.loads((src / "final.json").read_text())
    assert final["chair_0"] == {**shipped_final["chair_0"], "type": "small", "name": "my reading chair"}
    assert final["bed_0"] == shipped_final["bed_0"] and final["room_info"] == shipped_final["room_info"]


def test_objects_outside_the_observed_map_are_counted_and_refused(tmp_path):
    grid = GridSpec(200, 200, 0.05, (-3.0, 4.0))
    objset, _ = import_navchat(write_scene(tmp_path / "s"), NavchatFrame.from_first_pose(T_FIRST), "s")
    observed = np.zeros((200, 200), bool)
    logs = []
    with pytest.raises(InputDataError, match=r"field goals\.navchat_grid: 4 of 4 navchat objects lie outside the "
                                             r"observed map \(0 of \d+ object cells observed\)"):
        check_navchat_coverage(objset, grid, observed, 0.25, path="s", log=logs.append)
    bed = grid.world_to_cell(np.asarray(objset.by_key()["bed_0"].footprint))
    observed[:] = True
    observed[bed[:, 0].min():bed[:, 0].max() + 1, bed[:, 1].min():bed[:, 1].max() + 1] = False
    report = check_navchat_coverage(objset, grid, observed, 0.25, path="s", log=logs.append)
    assert report["objects_outside_observed"] == ["bed_0"]
    assert logs == ["navchat: 1 of 4 objects lie outside the observed map "
                    f"({report['object_cells_observed']} of {report['object_cells']} object cells observed): ['bed_0']"]


SHIPPED = os.environ.get("ZIPON_NAVCHAT_GOALS")  # navchat's orion/user_simulator/goals (never committed)


@pytest.mark.skipif(not SHIPPED, reason="set ZIPON_NAVCHAT_GOALS to navchat's orion/user_simulator/goals folder")
def test_navchats_shipped_scenes_import_and_export(tmp_path):
    frame = NavchatFrame.from_first_pose(T_FIRST)
    scenes = sorted(p for p in Path(SHIPPED).iterdir() if (p / "final.json").is_file())
    assert len(scenes) == 10
    for src in scenes:
        objset, doc = import_navchat(src, frame, src.name)
        write_navchat(tmp_path / src.name, *export_navchat(objset, doc, frame, source=src))
        assert (tmp_path / src.name / "objects.json").read_bytes() == (src / "objects.json").read_bytes()
        assert json.loads((tmp_path / src.name / "final.json").read_text()) == json.loads((src / "final.json").read_text())


# ----------------------------------------------------------------------------- the goals stage on navchat files

def _house_navchat(tmp_path: Path, frames_path: Path) -> Path:
    """The house's GT objects written as navchat files in navchat's own frame (anchored at the first pose)."""
    from pipeline.frames import FrameStore
    from pipeline.goals.objects import objects_from_gt

    fs = FrameStore(frames_path)
    frame = NavchatFrame.from_first_pose(fs.poses()[0])
    objset = objects_from_gt(fs.ground_truth, "house")
    objects, final = {}, {"room_info": {"bedroom": "Alice|Bob", "living room": "shared"}}
    for o in objset.objects:
        cells = frame.to_cells(o.footprint)
        objects[o.key] = {"name": o.cls, "center": frame.to_cells(o.mass_center).tolist(), "mass": 1.0,
                          "contour": [[[int(c), int(r)]] for c, r in cells]}
        if o.key in ("bed_0", "table_0"):
            final[o.key] = {"base": json.dumps({"center": objects[o.key]["center"], "mass": 1.0}), "nearby_obj": "",
                            "object_desc": "", "attr": None, "room_id": o.room, "explain": "", "type": "big"}
    folder = tmp_path / "navchat" / "house"
    folder.mkdir(parents=True)
    (folder / "objects.json").write_text(json.dumps(objects))
    (folder / "final.json").write_text(json.dumps(final, indent=2))
    return folder


def _goals_stage(tmp_path: Path, frames: Path, recon: Path, goals_params: dict):
    from pipeline.paramsfile import parse_params
    from pipeline.paths import Workspace
    from pipeline.engine.runner import StageContext
    from stages import STAGES
    from stages import goals as goals_stage

    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "params.yaml").write_text("scenes:\n  house: {source: simulate}\n")
    ws = Workspace.resolve(tmp_path / "params.yaml")
    params = parse_params({"scenes": {"house": {"source": "simulate"}}, "goals": goals_params})
    logs: list[str] = []
    ctx = StageContext.build(STAGES["goals"], params, "house", ws, {"frames": frames, "recon": recon},
                             {"goals": tmp_path / "goals.zarr"}, show_progress=False)
    ctx.log = logs.append
    return goals_stage.run(ctx), logs


def test_goals_stage_reads_navchat_files_in_navchats_frame(tmp_path):
    from pipeline.frames import FrameStore
    from pipeline.goals.objects import objects_from_gt
    from pipeline.goals.store import Goals
    from tests.fixtures.goal_scenes import write_house_artifacts

    frames, recon = write_house_artifacts(tmp_path, start_xy=(2.5, 1.8), start_yaw=0.4)
    folder = _house_navchat(tmp_path, frames)
    settings = {"objects": "navchat", "navchat_dirs": {"house": str(folder.relative_to(tmp_path))}}
    summary, _ = _goals_stage(tmp_path, frames, recon, settings)
    assert summary["objects_source"] == "navchat" and summary["goals"] == 2
    goals = Goals(tmp_path / "goals.zarr")
    bed = np.asarray(goals.objects["bed_0"].footprint)
    gt_bed = objects_from_gt(FrameStore(frames).ground_truth, "house").by_key()["bed_0"]
    assert np.abs(bed.mean(axis=0) - np.asarray(gt_bed.footprint).mean(axis=0)).max() < 0.08  # within ~1 cell
    # export-navchat from the built goals.zarr: the files come back as they were imported
    from pipeline.paramsfile import parse_params
    from pipeline.goals.navchat import export_scene

    params = parse_params({"scenes": {"house": {"source": "simulate"}}, "goals": settings})
    write_navchat(tmp_path / "exported", *export_scene(goals, params.goals, FrameStore(frames), "house", tmp_path))
    for name in ("objects.json", "final.json"):
        assert (tmp_path / "exported" / name).read_bytes() == (folder / name).read_bytes()
    # the same files read on the recon grid (the wrong frame): objects land off the observed map -> refused
    with pytest.raises(InputDataError, match=r"field goals\.navchat_grid: \d+ of 11 navchat objects lie outside the "
                                             r"observed map"):
        _goals_stage(tmp_path / "wrong", frames, recon, {**settings, "navchat_grid": {"origin": "recon_grid"},
                                                         "navchat_dirs": {"house": str(folder)}})


def test_frame_from_an_ingested_navchat_recording_matches_navchats_own_formula(tmp_path):
    """navchat's CoordinateTransform.agt2grd_pose, written out here from its Habitat base pose, against the frame
    zipon builds from the ingested recording's first camera pose (habitat_to_world + NavchatFrame)."""
    from pipeline.config import IngestParams
    from pipeline.frames import FrameStore
    from pipeline.readers.ingest import ingest_path
    from tests.fixtures.raw_datasets import make_recording, navchat_base, write_navchat

    root = write_navchat(tmp_path, make_recording(3))
    for sub, ext in (("rgb", "png"), ("depth", "npy"), ("semantic", "npy"), ("pose", "txt")):
        (root / sub / f"abcScene_0.{ext}").unlink()  # the recording starts at frame 1: turned 0.35 rad, moved
    ingest_path(root, tmp_path / "f.zarr", IngestParams(), log=lambda m: None)
    frame = NavchatFrame.from_first_pose(FrameStore(tmp_path / "f.zarr").poses()[0])
    p0, yaw0 = navchat_base(1)
    assert yaw0 != 0 and p0[0] != 0
    c, s = np.cos(yaw0), np.sin(yaw0)
    R_y = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # the base's rotation about Habitat's +y
    rng = np.random.default_rng(1)
    for q in p0 + rng.uniform(-6, 6, (200, 3)) * [1, 0, 1]:
        agent = R_y.T @ (q - p0)  # x right, z backward of the initial agent
        navchat_cell = [300 + int(agent[0] / 0.05), 300 + int(agent[2] / 0.05)]
        world = [q[0], -q[2]]  # Habitat (x, y, z) -> zipon (x, -z, y)
        assert frame.to_cells(world).tolist() == navchat_cell
