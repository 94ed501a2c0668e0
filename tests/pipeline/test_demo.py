"""``zipon demo``'s pictures (pipeline/demo.py) of a building: the grids once per floor."""

import zipon
from pipeline.demo import render_all


def test_a_buildings_pictures_draw_each_floors_grids(two_storey_maps):
    ws = two_storey_maps[0]
    scene = zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)["house"]
    written = {p.name for p in render_all([scene])}
    assert {f"{what}_floor{k}.png" for what in ("navigable", "color") for k in (0, 1)} <= written
    assert "color.png" not in written and "frames.png" in written


def test_a_buildings_goals_and_routes_are_drawn_per_floor(built_house):
    import zipon
    from pipeline.demo import render_all

    ws, _ = built_house
    scene = zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)["house"]
    written = {p.name for p in render_all([scene])}
    whats = ("plan", "goals", "routes", "navigable", "color")
    assert {f"{what}_floor{k}.png" for what in whats for k in (0, 1)} <= written
    assert not {f"{what}.png" for what in whats} & written
