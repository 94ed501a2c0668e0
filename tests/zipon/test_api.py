"""``import zipon`` on the session's tiny built scene: open, stores, queries, xarray views, run_eval, the docs' example."""

import re
from pathlib import Path

import numpy as np
import pytest

import zipon
from orion_eval.agents import Agent
from pipeline.errors import ConfigError, InputDataError, MissingInputError
from tests.fixtures.user_agents import NearestOnly

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ds(built_scene):
    ws, _ = built_scene
    return zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)


def test_open_from_params_folder_and_data_root(built_scene, ds, tmp_path):
    ws, _ = built_scene
    assert list(ds) == ["tiny"] and "tiny" in ds and len(ds) == 1
    assert zipon.open(ws.root).names == ["tiny"]  # the project folder
    by_root = zipon.open(ws.data_dir)  # a data root: params.yaml beside it is used
    assert by_root.names == ["tiny"] and by_root.workspace.data_dir == ws.data_dir
    with pytest.raises(MissingInputError, match="neither a params file"):
        zipon.open(tmp_path)
    with pytest.raises(ConfigError, match="unknown scene 'nope'"):
        ds["nope"]


def test_scene_hands_out_the_store_readers(built_scene, ds):
    ws, _ = built_scene
    scene = ds["tiny"]
    assert scene.frames.n_frames == 140 and scene.recon.grid == scene.vlmap.grid
    assert [g.id for g in scene.goals.goals] == [g.id for g in ds["tiny"].goals.goals]
    assert scene.episodes and all(e.goal_id in {g.id for g in scene.goals.goals} for e in scene.episodes)
    assert scene.path("vlmap") == ws.artifact("vlmap", "tiny")
    with pytest.raises(ConfigError, match="choose one of"):
        scene.map("octomap")


def test_missing_artifact_names_the_stage_to_run(built_scene, tmp_path):
    (tmp_path / "params.yaml").write_text("scenes:\n  empty: {source: simulate}\n")
    scene = zipon.open(tmp_path)["empty"]
    with pytest.raises(MissingInputError, match=r"no vlmap yet \(build it: zipon run -s empty --stage vlmap\)"):
        scene.vlmap


def test_query_matches_the_cli_library_and_checks_the_pose(built_scene, ds):
    from pipeline.maps.query import query_map

    ws, params = built_scene
    scene = ds["tiny"]
    goal = scene.goals.goals[0]
    cls = scene.goals.objects[goal.object_keys[0]].cls
    pose = scene.episodes[0].start
    got = scene.vlmap.query(cls, pose=pose)
    ref = query_map(ws.artifact("vlmap", "tiny"), ws.artifact("recon", "tiny"), cls, pose, params=params,
                    frames_path=ws.artifact("frames", "tiny"))
    assert got.candidates and [c.center_xy for c in got.candidates] == [c.center_xy for c in ref.candidates]
    d = [c.distance_m for c in got.candidates]
    assert d == sorted(d)
    x0, x1, y0, y1 = scene.vlmap.grid.extent_xy
    with pytest.raises(InputDataError, match=r"field pose: position .* lies off the map's grid"):
        scene.vlmap.query(cls, pose=(x1 + 5.0, y1, 0.0))
    with pytest.raises(InputDataError, match="field pose"):
        scene.vlmap.query(cls, pose=(1.0, float("nan"), 0.0))


def test_to_xarray_is_the_dense_grid_in_metres(ds):
    scene = ds["tiny"]
    smap = scene.vlmap.store
    grid = scene.vlmap.to_xarray()
    g = smap.grid
    assert grid.features.dims == ("y", "x", "feature")
    assert grid.features.shape == (g.rows, g.cols, smap.dim)
    assert grid.x.attrs["units"] == "m" and grid.top_z.attrs["units"] == "m"
    assert np.isclose(float(grid.x[0]), g.origin_xy[0] + g.cell_size_m / 2)
    assert float(grid.y[0]) > float(grid.y[-1])  # north-up: rows run south
    assert int(grid.observed.sum()) == smap.n_cells
    # one observed cell: the dense grid holds exactly the stored row; an unobserved one is NaN
    k = smap.n_cells // 2
    r, c = divmod(int(smap.cell[k]), g.cols)
    xy = g.cell_to_world(np.array([r, c]))
    vec = grid.features.sel(x=xy[0], y=xy[1], method="nearest").values
    assert np.array_equal(vec, smap.features16()[k])
    rr, cc = np.argwhere(~grid.observed.values)[0]
    assert np.isnan(grid.features[rr, cc].values).all()
    # features_at takes world metres and agrees with the grid
    feats, seen = scene.vlmap.features_at([xy, [1e6, 1e6]])
    assert seen.tolist() == [True, False]
    assert np.allclose(feats[0], vec.astype(np.float32)) and not feats[1].any()


def test_a_map_view_reads_a_region_lazily_tile_by_tile(ds, monkeypatch):
    import dask

    from pipeline.maps.store import SemanticMap
    from pipeline.region import Window
    from tests.fixtures.tiled_maps import chunk_reads

    scene = ds["tiny"]
    view = scene.vlmap
    g = view.grid
    whole = view.to_xarray()
    rows, cols = np.divmod(view.store.cell, g.cols)
    win = Window(int(rows.min()) + 10, int(rows.min()) + 90, int(cols.min()) + 20, int(cols.min()) + 120)
    x0, y1 = g.origin_xy
    s = g.cell_size_m  # the box of those cells, world metres
    box = (x0 + win.c0 * s, y1 - win.r1 * s, x0 + win.c1 * s, y1 - win.r0 * s)
    fresh = type(view)(scene, "vlmap")  # a view that has read nothing yet
    with chunk_reads(monkeypatch) as reads:
        part = fresh.to_xarray(region=box)
    assert "top/features" not in reads  # nothing of the features until computed
    assert part.features.shape == (80, 100, view.store.dim)
    np.testing.assert_allclose(part.x.values, whole.x.values[win.c0:win.c1], rtol=0, atol=1e-9)  # world metres
    np.testing.assert_array_equal(part.observed.values, whole.observed.values[win.slices])
    assert part.observed.values.any()
    with chunk_reads(monkeypatch) as reads, dask.config.set(scheduler="sync"):  # read here, where they are counted
        feats = part.features.values
    np.testing.assert_array_equal(feats, whole.features.values[win.slices])
    smap = SemanticMap(view.path)
    chunk = smap.group["top"]["features"].chunks[0]
    holding = {k for a, b in smap.row_ranges(win) for k in range(a // chunk, (b - 1) // chunk + 1)}
    assert 0 < reads["top/features"] and {int(k.split("/")[3]) for k in reads.keys_read if "features" in k} <= holding
    # a query of that box answers as the floor's query does there
    cls = scene.frames.ground_truth.objects[0].cls
    full, boxed = view.query(cls), view.query(cls, region=box)
    np.testing.assert_allclose(boxed.heatmap, full.heatmap[win.slices], rtol=0, atol=2e-6)
    assert boxed.grid == win.grid(g) and boxed.region is not None
    with pytest.raises(InputDataError, match=r"field region: x 1e\+06..1e\+06 m, y 0..1 m lies outside"):
        view.query(cls, region=(1e6, 0, 1e6 + 1, 1))
    with pytest.raises(InputDataError, match="field region: x runs from 2 to 1: inverted"):
        view.to_xarray(region=(2, 0, 1, 1))


def test_stores_open_in_xarray_with_named_dims_and_units(ds):
    import xarray as xr

    scene = ds["tiny"]
    recon = xr.open_zarr(scene.path("recon"), consolidated=False)
    assert recon.height.dims == ("row", "col") and recon.height.attrs["units"] == "m"
    assert recon.color.dims == ("row", "col", "rgb") and recon.pose.dims[0] == "frame"
    top = xr.open_zarr(scene.path("cfmap"), group="top", consolidated=False)
    assert top.features.dims == ("cell", "feature") and "long_name" in top.features.attrs
    assert top.index.dims == ("row", "col")
    vox = xr.open_zarr(scene.path("cfmap"), group="voxels", consolidated=False)
    assert vox.key.dims == ("voxel", "rcl")


def test_run_eval_accepts_user_agent_classes(ds, tmp_path):
    res = zipon.run_eval(ds, tmp_path, agents=["vlmap", NearestOnly], feedback=["yesno"], seeds=1, report=False)
    assert res["run"]["methods"] == ["vlmap", "nearest_only"] and res["run"]["seeds"] == [0]
    mine = [e for e in res["episodes"] if e["method"] == "nearest_only"]
    vl = [e for e in res["episodes"] if e["method"] == "vlmap"]
    assert len(mine) == len(vl) > 0 and all(e["talk_turns"] <= 1 for e in mine)
    # the first visit is the same as the built-in map agent's: never more successes than it
    assert sum(e["success"] for e in mine) <= sum(e["success"] for e in vl)
    assert (tmp_path / "results.json").is_file()


def test_run_eval_rejects_bad_agents_and_seeds(ds, tmp_path):
    class Nameless(Agent):
        def run(self, m, instruction, goal_name):
            pass

    class Impostor(NearestOnly):
        name = "orion"

    with pytest.raises(ConfigError, match="has no `name`"):
        zipon.run_eval(ds, tmp_path, agents=[Nameless])
    with pytest.raises(ConfigError, match="is taken by the registered OrionAgent"):
        zipon.run_eval(ds, tmp_path, agents=[Impostor])
    with pytest.raises(ConfigError, match="neither a method name nor a subclass"):
        zipon.run_eval(ds, tmp_path, agents=[object])
    with pytest.raises(ConfigError, match="seeds: expected a count"):
        zipon.run_eval(ds, tmp_path, agents=["vlmap"], seeds=0)
    with pytest.raises(ConfigError, match="--methods: unknown method"):
        zipon.run_eval(ds, tmp_path, agents=["gpt"])


def docs_example() -> str:
    """The Python block of the docs' Python API page (docs/reference/api.md, section "Example")."""
    text = (REPO / "docs" / "reference" / "api.md").read_text()
    section = text.split("## Example", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks, "the Python API page's Example section has no python block"
    return blocks[0]


def test_docs_example_runs(built_scene, monkeypatch, tmp_path, capsys):
    ws, _ = built_scene
    # the example opens "params.yaml" from the project folder: a copy beside the built data and manifests
    (tmp_path / "params.yaml").write_text(ws.params_path.read_text())
    (tmp_path / "data").symlink_to(ws.data_dir)
    (tmp_path / "manifests").symlink_to(ws.manifests_dir)
    monkeypatch.chdir(tmp_path)
    exec(compile(docs_example(), "docs/reference/api.md", "exec"), {"__name__": "docs_example"})
    out = capsys.readouterr().out
    assert "Scene('tiny'" in out and " deg" in out and "'episodes'" in out
    assert (tmp_path / "eval_api" / "results.json").is_file()


def test_the_demo_renders_through_the_shared_scene_handle(built_scene, tmp_path):
    from pipeline.demo import render_all
    from pipeline.scene import Scene

    ws, _ = built_scene
    src, dst = ws.data_dir / "artifacts" / "tiny", tmp_path / "artifacts" / "tiny"
    dst.mkdir(parents=True)
    for p in src.iterdir():  # the built artifacts, read in place; the pictures go to the copy's renders/
        if p.name != "renders":
            (dst / p.name).symlink_to(p)
    copy = zipon.open(ws.params_path, data_dir=tmp_path, manifests_dir=ws.manifests_dir)
    assert zipon.Scene is Scene and isinstance(copy["tiny"], Scene)
    written = render_all([copy["tiny"]])
    names = {p.name for p in written}
    assert {"frames.png", "plan.png", "navigable.png", "color.png", "goals.png", "routes.png"} <= names
    assert any(n.startswith("query_vlmap_") for n in names) and any(n.startswith("query_cfmap_") for n in names)
    assert all(p.parent == copy.workspace.renders("tiny") and p.stat().st_size > 0 for p in written)


def test_a_buildings_scene_has_floors_and_a_map_view_per_floor(two_storey_maps):
    from pipeline.maps.floors import FloorsResult
    from pipeline.maps.query import QueryResult

    ws = two_storey_maps[0]
    scene = zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)["house"]
    assert [round(f.floor_z_m, 2) for f in scene.floors] == [0.0, 3.0]
    views = scene.vlmap.floors
    assert [v.floor_index for v in views] == [0, 1] and "floor=1" in repr(views[1])
    assert views[1].store.floor_index == 1 and views[1].grid == scene.recon.floor(1).grid
    top_z = views[1].to_xarray()["top_z"].values
    assert np.nanmin(top_z) >= 3.0 - 0.1 and np.nanmax(scene.vlmap.floor(0).to_xarray()["top_z"].values) < 2.1
    with pytest.raises(InputDataError, match="a floor of scene 'house': 0..1"):
        scene.cfmap.floor(2)
    every = scene.vlmap.query("bed")
    assert isinstance(every, FloorsResult) and {c.floor for c in every.candidates} == {1}
    one = views[0].query("sofa", (3.0, 2.0, 0.0))
    assert isinstance(one, QueryResult) and one.floor == 0 and one.candidates[0].distance_m is not None
    with pytest.raises(InputDataError, match="pose_floor"):
        scene.vlmap.query("bed", (3.0, 2.0, 0.0), pose_floor=2)
    with pytest.raises(InputDataError, match="off the map's grid"):
        scene.vlmap.query("bed", (300.0, 2.0, 0.0), pose_floor=1)
