"""The goals stage's work as a library call (:func:`pipeline.goals.build.build_scene_goals`) and its parts,
on the hand-made house (GT frames.zarr + GT-grid recon.zarr)."""

import numpy as np
import pytest
from scipy import ndimage

from pipeline.config import GoalsParams, TaskParams
from pipeline.errors import ConfigError, InputDataError
from pipeline.frames import FrameStore
from pipeline.goals.build import (OBJECT_MARGIN_M, WALL_MIN_HEIGHT_M, build_scene_goals, load_objects, start_pose,
                                  wall_grid)
from pipeline.goals.edits import export_goals
from pipeline.goals.objects import rasterize_polygons
from pipeline.goals.store import ARTIFACT, FORMAT_VERSION, Goals
from pipeline.recon import OCCUPIED, Recon
from pipeline.scene_gt import GTScene
from pipeline.store import artifact_attrs
from tests.fixtures.goal_scenes import write_house_artifacts


@pytest.fixture(scope="module")
def house(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("house_goals")
    frames, recon = write_house_artifacts(tmp, start_xy=(2.5, 1.8), start_yaw=0.4)
    frames, recon = FrameStore(frames), Recon(recon)
    return tmp, frames, recon, _build(tmp, frames, recon, "goals.zarr")


def _build(tmp, frames, recon, out, **goals):
    return build_scene_goals(frames, recon, tmp / out, artifact_attrs(ARTIFACT, FORMAT_VERSION, "goals", "test"),
                             scene="house", goals=GoalsParams(**goals), task=TaskParams(), root=tmp,
                             log=lambda m: None)


def test_build_scene_goals_writes_the_goals_of_the_scene(house):
    tmp, frames, recon, summary = house
    goals = Goals(tmp / "goals.zarr")
    assert summary["goals"] == len(goals.goals) == 10 and summary["objects"] == 11
    assert summary["objects_source"] == "gt" and summary["edited"] is False
    assert summary["big"] + summary["small"] + summary["ambiguous"] == 10
    np.testing.assert_allclose(goals.attrs["start_pose"], (2.5, 1.8, 0.4), atol=1e-6)


def test_an_edits_file_changed_after_import_is_refused_and_nothing_is_written(house):
    tmp, frames, recon, _ = house
    export_goals(tmp / "goals.zarr", tmp / "edited.yaml")  # never imported: its name carries no digest
    with pytest.raises(InputDataError, match="is not in the file name; the file was changed after import"):
        _build(tmp, frames, recon, "goals_edited.zarr", edits={"house": "edited.yaml"})
    assert not (tmp / "goals_edited.zarr").exists()


def test_objects_from_a_file_without_a_file_is_a_config_error_naming_the_key(house):
    tmp, frames, recon, _ = house
    with pytest.raises(ConfigError, match=r"goals\.objects_files\.house: no objects file given"):
        load_objects("house", frames, recon.grid, GoalsParams(objects="file"), tmp)


def test_walls_are_gt_walls_or_occupied_cells_away_from_objects(house):
    _, frames, recon, _ = house
    objset, _, gt = load_objects("house", frames, recon.grid, GoalsParams(), recon.path)
    assert isinstance(gt, GTScene)
    index = rasterize_polygons([np.asarray(o.footprint) for o in objset.objects], recon.grid)
    walls_gt = wall_grid(objset, recon, gt, index)
    assert np.array_equal(walls_gt, gt.occupancy(recon.grid, WALL_MIN_HEIGHT_M, gt.wall_height_m, objects=False))
    walls = wall_grid(objset, recon, None, index)
    margin = ndimage.binary_dilation(index > 0, iterations=round(OBJECT_MARGIN_M / recon.grid.cell_size_m))
    occupied = recon.occupancy == OCCUPIED
    assert not (walls & margin).any() and np.array_equal(walls, occupied & ~margin)
    assert (occupied & margin).sum() > 0  # objects' own occupied cells were left out
    assert (walls & walls_gt).sum() > 0.8 * walls_gt.sum()  # the GT walls are occupied cells away from objects


def test_start_pose_is_the_first_camera_pose(house):
    _, frames, _, _ = house
    x, y, yaw = start_pose(frames)
    assert (x, y) == pytest.approx((2.5, 1.8)) and yaw == pytest.approx(0.4)


def test_ambiguous_goals_are_picked_among_classes_with_three_or_more_instances():
    from collections import Counter

    from pipeline.config import SimulateParams
    from pipeline.goals.build import AMBIGUOUS_MIN_GROUPS, select_groups
    from pipeline.goals.naming import same_goal_groups
    from pipeline.goals.objects import objects_from_gt
    from pipeline.sim import generate_scene

    for name in ("sim_00", "sim_03", "sim_07"):
        objset = objects_from_gt(generate_scene(name, SimulateParams(seed=2)))
        groups = same_goal_groups(sorted(objset.objects, key=lambda o: o.key), 2.0)
        cls = {g: objset.by_key()[g[0]].cls for g in groups}
        per_cls = Counter(cls.values())
        picked = select_groups(objset, groups, GoalsParams(max_goals=12), np.random.default_rng(0))
        ambiguous = [cls[g] for g, t in picked if t == "ambiguous"]
        assert len(picked) == 12 and len(ambiguous) >= 4
        assert all(per_cls[c] >= AMBIGUOUS_MIN_GROUPS for c in ambiguous), (name, ambiguous)
        assert len(set(ambiguous)) >= 3  # spread over the classes, not four pictures


def test_spread_ambiguous_takes_big_classes_first_one_group_per_class_in_turn():
    from pipeline.goals.build import spread_ambiguous

    pool = [("cup_0",), ("chair_0",), ("chair_1",), ("cup_1",), ("lamp_0",), ("chair_2",), ("lamp_1",), ("lamp_2",)]
    cls_of = {g: g[0].split("_")[0] for g in pool}
    out = spread_ambiguous(pool, cls_of, {"cup": 2, "chair": 3, "lamp": 3})
    assert out == [("chair_0",), ("lamp_0",), ("chair_1",), ("lamp_1",), ("chair_2",), ("lamp_2",), ("cup_0",),
                   ("cup_1",)]


def test_goal_regions_read_a_window_per_object_are_the_whole_meshs(tmp_path, monkeypatch):
    """The house's mesh cut into small triangles and written canonically (as reconstruct writes it): the goals stage
    reads a window of it around each goal object, in one pass, and writes the store the whole mesh gives."""
    import open3d as o3d

    import pipeline.goals.build as goals_build
    from pipeline.nav.region import MeshSight
    from pipeline.nav.sight import WindowedSight
    from pipeline.recon.store import write_mesh

    frames, recon = write_house_artifacts(tmp_path, start_xy=(2.5, 1.8), start_yaw=0.4)
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "recon_mesh.ply"))
    while np.ptp(np.asarray(mesh.vertices)[np.asarray(mesh.triangles)], axis=1).max() > 0.4:
        mesh = mesh.subdivide_midpoint(1)
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.full((len(mesh.vertices), 3), 0.5))
    write_mesh(tmp_path / "recon_mesh.ply", mesh)
    frames, recon = FrameStore(frames), Recon(recon)
    windowed: list[WindowedSight] = []

    class Spy(WindowedSight):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            windowed.append(self)

    monkeypatch.setattr(goals_build, "WindowedSight", Spy)
    _build(tmp_path, frames, recon, "windowed.zarr")

    class Whole:  # the whole mesh in one ray-casting scene, as before windows
        def __init__(self, mesh_path, *, floor_z, camera_height_m, grid, tolerance_m=0.15):
            self.sight = MeshSight.from_mesh(mesh_path, floor_z=floor_z, camera_height_m=camera_height_m, grid=grid,
                                             tolerance_m=tolerance_m)
            self.tolerance = self.sight.tolerance

        def prepare(self, boxes):
            pass

        def __call__(self, *args, **kwargs):
            return self.sight(*args, **kwargs)

    monkeypatch.setattr(goals_build, "WindowedSight", Whole)
    _build(tmp_path, frames, recon, "whole.zarr")
    a, b = Goals(tmp_path / "windowed.zarr"), Goals(tmp_path / "whole.zarr")
    assert a.attrs == b.attrs and len(a.goals) == 10
    for name in ("object_index", "region_cells", "region_offset"):
        np.testing.assert_array_equal(a.group[name][...], b.group[name][...])
    assert sum(a.goal_region(g.id).any() for g in a.goals) >= 8
    (sight,) = windowed
    assert sight.reads == 1 and len(sight.windows) == sum(len(g.object_keys) for g in a.goals)
    held = max(len(w.triangles) for w in sight.windows)
    assert held < 0.6 * len(mesh.triangles)  # each window holds part of the house


def test_a_start_too_far_from_seen_floor_is_said_in_the_log_and_its_goals_get_no_procedural_feedback(tmp_path):
    frames, recon = write_house_artifacts(tmp_path, start_xy=(-6.0, -6.0), start_yaw=0.4)  # far outside the house
    lines = []
    summary = build_scene_goals(FrameStore(frames), Recon(recon), tmp_path / "goals.zarr",
                                artifact_attrs(ARTIFACT, FORMAT_VERSION, "goals", "test"), scene="house",
                                goals=GoalsParams(), task=TaskParams(), root=tmp_path, log=lines.append)
    assert summary["goals"] > 0 and summary["with_procedural"] == 0
    assert any("the recording's start lies more than" in m and "its goals get no procedural feedback" in m
               for m in lines), lines
