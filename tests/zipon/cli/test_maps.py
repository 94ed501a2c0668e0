"""``zipon render`` and ``zipon query`` on a building (zipon/cli/maps.py): a picture per floor, ``--floor``, and
candidates that say their floor; wrong floors are refused naming the option (the two-storey house fixture)."""

import json

from zipon.cli import main


def cli(ws, *args) -> int:
    return main(["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), *args])


def test_render_draws_each_floor_of_a_building_or_the_one_asked_for(two_storey_maps, tmp_path, capsys):
    ws = two_storey_maps[0]
    capsys.readouterr()
    assert cli(ws, "render", "house", "--what", "color", "-o", str(tmp_path / "color.png")) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "color_floor0.png"), str(tmp_path / "color_floor1.png")]
    assert (tmp_path / "color_floor0.png").stat().st_size != (tmp_path / "color_floor1.png").stat().st_size
    assert cli(ws, "render", "house", "--what", "cfmap", "--floor", "1") == 0
    assert capsys.readouterr().out.split() == [str(ws.renders("house") / "cfmap_floor1.png")]
    assert (ws.renders("house") / "cfmap_floor1.png").is_file()


def test_render_refuses_a_floor_the_scene_has_not_or_a_whole_scene_picture(two_storey_maps, capsys):
    ws = two_storey_maps[0]
    capsys.readouterr()
    assert cli(ws, "render", "house", "--what", "navigable", "--floor", "2") == 1
    err = capsys.readouterr().err
    assert "--floor" in err and "has 2 floors: 0 (floor 0, 0.00 m), 1 (floor 1, 3.00 m)" in err and "0..1" in err
    assert cli(ws, "render", "house", "--what", "frames", "--floor", "1") == 1
    assert "--floor applies to obstacles, navigable, color, height, vlmap, cfmap, goals, routes" in \
        capsys.readouterr().err


def test_goals_and_routes_are_drawn_per_floor_of_a_building(built_house, built_scene, tmp_path, capsys):
    ws = built_house[0]
    capsys.readouterr()
    assert cli(ws, "render", "house", "--what", "routes", "-o", str(tmp_path / "routes.png")) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "routes_floor0.png"), str(tmp_path / "routes_floor1.png")]
    assert cli(ws, "render", "house", "--what", "goals", "--floor", "1") == 0
    assert capsys.readouterr().out.split() == [str(ws.renders("house") / "goals_floor1.png")]
    assert cli(ws, "render", "house", "--what", "goals", "--floor", "2") == 1
    assert "has 2 floors: 0 (floor 0, 0.00 m), 1 (floor 1, 2.86 m)" in capsys.readouterr().err
    # the ground truth's plan: one per floor too
    assert cli(ws, "render", "house", "--what", "plan", "-o", str(tmp_path / "plan.png")) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "plan_floor0.png"), str(tmp_path / "plan_floor1.png")]
    assert cli(ws, "render", "house", "--what", "plan", "--floor", "1", "-o", str(tmp_path / "one.png")) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "one_floor1.png")]
    assert cli(ws, "render", "house", "--what", "plan", "--floor", "2", "-o", str(tmp_path / "two.png")) == 1
    assert "--floor" in (err := capsys.readouterr().err) and "ground truth has 2 floors: 0 (" in err
    assert not list(tmp_path.glob("two*.png"))
    # a single-floor scene: one picture, named as it always was; it has no floor 1
    tiny = built_scene[0]
    assert cli(tiny, "render", "tiny", "--what", "goals", "-o", str(tmp_path / "goals.png")) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "goals.png")]
    assert cli(tiny, "render", "tiny", "--what", "routes", "--floor", "1", "-o", str(tmp_path / "r.png")) == 1
    assert "scene 'tiny' has 1 floor: 0 (floor 0," in capsys.readouterr().err and not (tmp_path / "r.png").exists()


def test_query_answers_from_every_floor_with_the_floor_of_each_candidate(two_storey_maps, tmp_path, capsys):
    ws = two_storey_maps[0]
    capsys.readouterr()
    assert cli(ws, "query", "house", "bed", "--json", "--png", str(tmp_path / "bed.png")) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [f["floor"] for f in doc["floors"]] == [0, 1] and (tmp_path / "bed.png").is_file()
    assert doc["candidates"] and {c["floor"] for c in doc["candidates"]} == {1}
    assert doc["candidates"][0]["gt_class"] == "bed"
    assert cli(ws, "query", "house", "table", "--map", "cfmap") == 0
    table = capsys.readouterr().out
    assert "floor" in table and "floor 0" in table and "floor 1" in table
    # a pose upstairs: that floor's table first, with its distance
    assert cli(ws, "query", "house", "table", "--pose", "3,2.6,0", "--pose-floor", "1", "--json") == 0
    first = json.loads(capsys.readouterr().out)["candidates"][0]
    assert first["floor"] == 1 and first["distance_m"] is not None and first["angle_deg"] is not None


def test_query_limited_to_one_floor(two_storey_maps, capsys):
    ws = two_storey_maps[0]
    capsys.readouterr()
    assert cli(ws, "query", "house", "bed", "--floor", "0") == 0
    assert capsys.readouterr().out.startswith("floor 0: no candidates for 'bed'")
    assert cli(ws, "query", "house", "sofa", "--floor", "0", "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["floor"] == 0 and [c["gt_class"] for c in doc["candidates"]] == ["sofa"]
    assert cli(ws, "query", "house", "sofa", "--floor", "3") == 1
    assert "--floor" in capsys.readouterr().err
    assert cli(ws, "query", "house", "sofa", "--floor", "1", "--pose", "3,2,0", "--pose-floor", "0") == 1
    assert "with --floor the pose stands on that floor" in capsys.readouterr().err
    assert cli(ws, "query", "house", "sofa", "--pose", "3,2,0", "--pose-floor", "4") == 1
    assert "--pose-floor" in capsys.readouterr().err


def test_render_and_query_a_region(two_storey_maps, tmp_path, capsys):
    from pipeline.recon import Recon

    ws = two_storey_maps[0]
    x0, x1, y0, y1 = Recon(ws.artifact("recon", "house")).grid.extent_xy
    capsys.readouterr()
    # the whole floor's sofa, then the same query in a box around it: the same candidate, the box's grid
    assert cli(ws, "query", "house", "sofa", "--floor", "0", "--json") == 0
    sofa = json.loads(capsys.readouterr().out)["candidates"][0]
    sx, sy = sofa["center_xy"]
    box = [f"{v:g}" for v in (sx - 1.0, sy - 1.0, sx + 1.0, sy + 1.0)]
    assert cli(ws, "query", "house", "sofa", "--floor", "0", "--json", "--region", *box,
               "--png", str(tmp_path / "sofa.png")) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["region"] == dict(zip(("x0", "y0", "x1", "y1"), map(float, box)))
    assert [c["center_xy"] for c in doc["candidates"]] == [sofa["center_xy"]]
    assert doc["cells_observed"] <= 41 * 41 and (tmp_path / "sofa.png").is_file()
    for what in ("color", "vlmap"):
        out = tmp_path / f"{what}.png"
        assert cli(ws, "render", "house", "--what", what, "--floor", "1", "--region", *box, "-o", str(out)) == 0
        drawn = tmp_path / f"{what}_floor1.png"  # a building's picture names its floor
        assert capsys.readouterr().out.split() == [str(drawn)] and drawn.is_file()


def test_a_bad_region_is_one_line_naming_the_option(two_storey_maps, tmp_path, capsys):
    from pipeline.recon import Recon

    ws = two_storey_maps[0]
    x0, x1, y0, y1 = Recon(ws.artifact("recon", "house")).grid.extent_xy
    outside = [f"{x1 + 1:g}", "0", f"{x1 + 3:g}", "1"]
    for args, message in (
        (["render", "house", "--what", "color", "--region", "1", "2", "0", "3"], "x runs from 1 to 0: inverted"),
        (["render", "house", "--what", "vlmap", "--floor", "0", "--region", "0", "2", "1", "2"],
         "y runs from 2 to 2: empty"),
        (["render", "house", "--what", "height", "--region", *outside], "lies outside the floor's grid"),
        (["query", "house", "sofa", "--region", *outside], "lies outside the floor's grid"),
        (["query", "house", "sofa", "--floor", "0", "--region", "0", "3", "1", "-3"], "y runs from 3 to -3: inverted"),
        (["render", "house", "--what", "goals", "--region", "0", "0", "1", "1"],
         "--region: --what goals is drawn whole; --region applies to obstacles, navigable, color, height, vlmap"),
    ):
        assert cli(ws, *args, "-o" if args[0] == "render" else "--png", str(tmp_path / "x.png")) == 1, args
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "--region" in err and message in err and "\n" not in err, err
        assert not (tmp_path / "x.png").exists()
