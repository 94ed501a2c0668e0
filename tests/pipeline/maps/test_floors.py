"""Maps of a building, floor by floor: the two-storey house (tests.fixtures.map_scenes) built by the map stages
gives a version 2 store with one map per floor, each holding only its floor's objects; queries answer per floor
and across floors (pipeline.maps.floors); a damaged building store is refused with a message naming what is wrong."""

import shutil
import json

import numpy as np
import pytest

from pipeline.errors import ArtifactError, InputDataError
from pipeline.maps.floors import query_floors
from pipeline.maps.query import open_query
from pipeline.maps.render import render_map_pca, render_query
from pipeline.pictures import AXIS_BOTTOM, AXIS_LEFT
from pipeline.maps.store import BUILDING_FORMAT_VERSION, SemanticMap
from pipeline.recon import Recon


def _paths(two_storey_maps):
    ws = two_storey_maps[0]
    return {name: ws.artifact(name, "house") for name in ("frames", "recon", "vlmap", "cfmap")}


def test_a_buildings_maps_hold_one_map_per_floor_on_its_grid_and_lattice(two_storey_maps):
    _, _, _, summaries = two_storey_maps
    art = _paths(two_storey_maps)
    recon = Recon(art["recon"])
    assert [round(f.floor_z_m, 2) for f in recon.floors] == [0.0, 3.0]
    for name in ("vlmap", "cfmap"):
        floors = [SemanticMap(art[name], k) for k in (0, 1)]
        assert floors[0].attrs["format_version"] == BUILDING_FORMAT_VERSION
        assert floors[0].floors == recon.floors
        for k, m in enumerate(floors):
            assert m.floor_index == k and m.floor == recon.floors[k]
            assert m.grid == recon.floor(k).grid and m.lattice.floor_z == pytest.approx(recon.floors[k].floor_z_m)
            assert m.n_cells == summaries[name]["floors"][k]["cells"] > 1000
            assert m.meta.n_cells == m.n_cells and m.meta.cells_filled == summaries[name]["floors"][k]["cells_filled"]
        assert summaries[name]["cells"] == floors[0].n_cells + floors[1].n_cells
        # the root reads as floor 0, as a single-floor reader sees it
        assert np.array_equal(SemanticMap(art[name]).cell, floors[0].cell)
        assert floors[0].floor_map(1).n_cells == floors[1].n_cells
    cf1 = SemanticMap(art["cfmap"], 1)
    assert len(cf1.voxels()) == summaries["cfmap"]["floors"][1]["voxels"]
    assert (cf1.voxels().key[:, 2] >= 0).all()


@pytest.mark.parametrize("name", ["vlmap", "cfmap"])
def test_each_floors_map_holds_only_the_objects_of_its_floor(two_storey_maps, name):
    _, params, _, _ = two_storey_maps
    art = _paths(two_storey_maps)
    mq = [open_query(art[name], params, recon_path=art["recon"], frames_path=art["frames"], floor=k) for k in (0, 1)]
    found = {(k, text): {c.gt_class for c in mq[k].query(text).candidates} for k in (0, 1) for text in ("sofa", "bed")}
    print(name, found)
    assert found[(0, "sofa")] == {"sofa"} and found[(1, "bed")] == {"bed"}
    assert found[(0, "bed")] == set() and found[(1, "sofa")] == set()  # no upstairs bed seen through the slab
    tables = [[(c.floor, c.gt_instance) for c in q.query("table").candidates] for q in mq]
    assert tables == [[(0, 1)], [(1, 2)]]  # each floor's table, labelled with that floor's ground truth


def test_a_query_of_every_floor_ranks_them_together_and_a_pose_stands_on_one_floor(two_storey_maps):
    _, params, _, _ = two_storey_maps
    art = _paths(two_storey_maps)
    mq = [open_query(art["vlmap"], params, recon_path=art["recon"], frames_path=art["frames"], floor=k) for k in (0, 1)]
    result = query_floors(mq, "table")
    assert [(c.obj_id, c.floor) for c in result.candidates] == [(1, 0), (2, 1)] or \
        [(c.obj_id, c.floor) for c in result.candidates] == [(1, 1), (2, 0)]
    assert all(c.distance_m is None for c in result.candidates)
    doc = json.loads(json.dumps(result.to_json()))
    assert [f["floor"] for f in doc["floors"]] == [0, 1] and doc["floors"][1]["floor_name"] == "floor 1"
    assert sorted(c["floor"] for c in doc["candidates"]) == [0, 1]
    # a pose upstairs: floor 1's table first with its distance, the other floor's after it without one
    upstairs = query_floors(mq, "table", (3.0, 2.6, 0.0), pose_floor=1)
    first, second = upstairs.candidates
    assert (first.floor, second.floor) == (1, 0) and first.distance_m is not None and second.distance_m is None
    assert upstairs.floors[1].candidates[0].obj_id == 1 and upstairs.floors[0].candidates[0].obj_id == 2
    assert len(query_floors(mq, "table", max_candidates=1).candidates) == 1
    with pytest.raises(InputDataError, match="pose floor"):
        query_floors(mq, "table", (3.0, 2.6, 0.0), pose_floor=2)


def test_pictures_of_a_buildings_query_and_of_each_floors_map(two_storey_maps, tmp_path):
    import cv2

    _, params, _, _ = two_storey_maps
    art = _paths(two_storey_maps)
    mq = [open_query(art["cfmap"], params, recon_path=art["recon"], frames_path=art["frames"], floor=k) for k in (0, 1)]
    one = cv2.imread(str(render_query(mq[0].query("bed"), tmp_path / "one.png")))
    both = cv2.imread(str(render_query(query_floors(mq, "bed"), tmp_path / "both.png")))
    assert both.shape[1] > 1.9 * one.shape[1]  # the floors side by side
    for k in (0, 1):
        pca = cv2.imread(str(render_map_pca(art["vlmap"], tmp_path / f"pca{k}.png", floor=k)))
        assert (pca[:-AXIS_BOTTOM, AXIS_LEFT - 1] < 100).all(axis=-1).mean() > 0.9  # metre axes on a building's floor
    assert (both[40:200, AXIS_LEFT - 1] < 100).all(axis=-1).all() and not (one[40:200, AXIS_LEFT - 1] < 100).all()


def test_a_damaged_building_store_is_refused_naming_what_is_wrong(two_storey_maps, tmp_path):
    art = _paths(two_storey_maps)
    with pytest.raises(ArtifactError, match=r"no floor 2; this map has 2 floors \(0..1\)"):
        SemanticMap(art["vlmap"], 2)
    broken = shutil.copytree(art["vlmap"], tmp_path / "vlmap.zarr")
    shutil.rmtree(broken / "floors" / "1")
    SemanticMap(broken, 0)  # floor 0 still reads
    with pytest.raises(ArtifactError, match="floors/1 missing .floor 1 listed in attrs.floors.; rebuild it"):
        SemanticMap(broken, 1)
    meta = json.loads((broken / "zarr.json").read_text())
    del meta["attributes"]["floors"]
    (broken / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(ArtifactError, match="attrs.floors missing in a format_version 2 store"):
        SemanticMap(broken)
