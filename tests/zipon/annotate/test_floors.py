"""The annotation server on a building (the simulated two-storey house built by ``zipon run``): every floor's layers,
objects, rooms, goals, routes and trajectory carry their floor, the frames that saw a place and the map proposals
are read on the floor asked for, the route preview crosses floors over the stairs and from the recording's start says
each goal's stored procedural feedback word for word, an objects file keeps the floor of what is placed on it, and a
floor the scene does not have is refused naming the floors it has. A single-floor scene is floor 0 throughout."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from tests.zipon.annotate.conftest import ORIGIN, SCENE, scene_summary, copy_built, make_client, png, refused

W = {"headers": {"Origin": ORIGIN}}
HOUSE = "house"


@pytest.fixture(scope="module")
def house_root(built_house, tmp_path_factory):
    return copy_built(built_house[0], tmp_path_factory.mktemp("annotate_house") / "ws")


@pytest.fixture(scope="module")
def client(house_root):
    return make_client(house_root)


@pytest.fixture(scope="module")
def summary(client):
    return scene_summary(client, HOUSE)






def test_the_summary_gives_the_floors_and_stairs_and_each_record_its_floor(summary, house_root):
    from pipeline.goals.store import Goals
    from pipeline.recon import Recon

    art = house_root / "data" / "artifacts" / HOUSE
    recon, goals = Recon(art / "recon.zarr"), Goals(art / "goals.zarr")
    assert [f["id"] for f in summary["floors"]] == [0, 1]
    assert summary["floors"][1]["floor_z_m"] == pytest.approx(recon.floors[1].floor_z_m, abs=1e-3)
    assert recon.floors[1].floor_z_m > 2.0
    (stair,) = summary["stairs"]
    assert (stair["bottom"]["floor"], stair["top"]["floor"]) == (0, 1)
    assert stair["bottom"]["xy"] == pytest.approx(list(recon.stairs[0].bottom.xy), abs=1e-3)
    assert {o["key"]: o["floor"] for o in summary["objects"]} == {k: o.floor for k, o in goals.objects.items()}
    assert {g["id"]: g["floor"] for g in summary["goals"]} == {g.id: g.floor for g in goals.goals}
    assert {g["floor"] for g in summary["goals"]} == {0, 1}
    rooms = {r["id"]: r["floor"] for r in summary["rooms"]}
    assert rooms["living_room_1"] == 0 and rooms["bedroom_1"] == 1
    # a cross-floor episode is cut into its floors' legs, joined at the stair's ends
    cross = [r for r in summary["routes"] if len(r["legs"]) > 1]
    assert cross and all(sum(len(leg["path"]) for leg in r["legs"]) == len(r["path"]) for r in summary["routes"])
    for r in cross:
        first, last = r["legs"][0], r["legs"][-1]
        assert first["floor"] == r["start_floor"] != last["floor"]
        foot, head = stair["bottom"] if first["floor"] == 0 else stair["top"], \
            stair["top"] if first["floor"] == 0 else stair["bottom"]
        assert math.dist(first["path"][-1], foot["xy"]) < 0.5 and math.dist(last["path"][0], head["xy"]) < 0.5
    # each camera pose carries the floor it stood on: the walk starts downstairs and climbs
    floors = [p[3] for p in summary["trajectory"]]
    assert floors[0] == 0 and set(floors) == {0, 1}


def test_each_floor_has_its_own_layers(client, summary):
    grid = summary["grid"]
    for name in ("color", "navigable", "occupancy", "rooms"):
        lower = png(client.get(f"/api/scenes/{HOUSE}/layers/{name}.png", params={"floor": 0}))
        upper = png(client.get(f"/api/scenes/{HOUSE}/layers/{name}.png", params={"floor": 1}))
        assert lower.shape[:2] == upper.shape[:2] == (grid["rows"], grid["cols"])
        assert not np.array_equal(lower, upper), name
    # no floor named: floor 0, as a single-floor scene's page asks
    assert np.array_equal(png(client.get(f"/api/scenes/{HOUSE}/layers/color.png")),
                          png(client.get(f"/api/scenes/{HOUSE}/layers/color.png", params={"floor": 0})))


@pytest.mark.parametrize("path, params", [
    ("layers/color.png", {}),
    ("seen", {"x": 3.0, "y": 3.0}),
    ("propose", {"text": "bed"}),
    ("route", {"x": 3.0, "y": 3.0, "objects": "couch_0"}),
])
@pytest.mark.parametrize("floor, words", [
    ("2", ("floor 2: scene house has 2 floors: 0 (floor 0, 0.00 m), 1 (floor 1,",)),
    ("-1", ("floor -1: scene house has 2 floors",)),
    ("one", ("floor='one' is not an integer",)),
])
def test_a_floor_the_scene_lacks_is_refused_naming_its_floors(client, path, params, floor, words):
    refused(client.get(f"/api/scenes/{HOUSE}/{path}", params={**params, "floor": floor}), 400, "floor", *words)


def test_the_route_preview_from_the_recorded_start_says_every_goals_stored_procedural_feedback(client, house_root):
    """As the goals stage does for a building: from the recording's start on its floor, over the stairs."""
    from pipeline.goals.store import Goals

    goals = Goals(house_root / "data" / "artifacts" / HOUSE / "goals.zarr")
    climbs = 0
    for goal in goals.goals:
        body = client.get(f"/api/scenes/{HOUSE}/route", params={"objects": ",".join(goal.object_keys)}).json()
        stored = goal.feedback["procedural"]
        assert body["start_floor"] == 0 and body["goal_floor"] == goal.floor
        assert body["start"] == pytest.approx(list(goals.attrs["start_pose"]))
        if stored is None:
            assert not body["reachable"] or body["text"] == "", (goal.id, body)
            continue
        assert body["reachable"] and body["text"] == stored, (goal.id, body["text"], stored)
        assert [leg["floor"] for leg in body["legs"]] == ([0] if goal.floor == 0 else [0, 1])
        if goal.floor == 1:
            climbs += 1
            assert "go up the stairs; at the top" in body["text"]
            (stair,) = body["stairs"]
            assert stair["up"] and (stair["from_floor"], stair["to_floor"]) == (0, 1)
            assert math.dist(body["legs"][0]["path"][-1], stair["from_xy"]) < 0.5
            assert math.dist(body["legs"][1]["path"][0], stair["to_xy"]) < 0.5
            assert body["length_m"] > sum(math.dist(a, b) for leg in body["legs"]
                                          for a, b in zip(leg["path"], leg["path"][1:]))  # + the stair's slope
    assert climbs >= 2


def test_a_route_picked_upstairs_goes_down_to_a_goal_downstairs(client, summary):
    goal = next(g for g in summary["goals"] if g["floor"] == 0)
    start = next(r for r in summary["routes"] if r["start_floor"] == 1)["start"]
    body = client.get(f"/api/scenes/{HOUSE}/route", params={"x": start[0], "y": start[1], "floor": 1,
                                                            "objects": ",".join(goal["objects"])}).json()
    assert body["reachable"] and body["start_floor"] == 1 and body["goal_floor"] == 0
    assert [leg["floor"] for leg in body["legs"]] == [1, 0]
    assert "go down the stairs; at the bottom" in body["text"]
    assert body["stairs"][0]["from_floor"] == 1 and not body["stairs"][0]["up"]
    # the same point taken on floor 0 is another place: a route that stays downstairs
    down = client.get(f"/api/scenes/{HOUSE}/route", params={"x": start[0], "y": start[1], "floor": 0,
                                                            "objects": ",".join(goal["objects"])}).json()
    assert not down["reachable"] or "stairs" not in down["text"]


def test_the_frames_that_saw_a_place_and_the_proposals_are_of_the_floor_asked(client, summary):
    upper, lower = summary["floors"][1], summary["floors"][0]
    bed = next(o for o in summary["objects"] if o["cls"] == "bed")
    assert bed["floor"] == 1
    x, y = bed["mass_center"]
    seen = client.get(f"/api/scenes/{HOUSE}/seen", params={"x": x, "y": y, "floor": 1}).json()
    assert seen["frames"] and seen["z"] > upper["floor_z_m"]
    below = client.get(f"/api/scenes/{HOUSE}/seen", params={"x": x, "y": y, "floor": 0}).json()
    assert below["z"] < upper["floor_z_m"] - 0.1 and below["z"] >= lower["floor_z_m"] - 0.01
    assert not {f["frame"] for f in seen["frames"]} & {f["frame"] for f in below["frames"]}
    up = client.get(f"/api/scenes/{HOUSE}/propose", params={"text": "bed", "floor": 1}).json()
    down = client.get(f"/api/scenes/{HOUSE}/propose", params={"text": "bed", "floor": 0}).json()
    assert up["floor"] == 1 and up["proposals"] and down["floor"] == 0 and not down["proposals"]


def test_an_objects_file_keeps_each_objects_floor_and_refuses_a_floor_the_scene_lacks(built_house, tmp_path):
    from pipeline.goals.objects import objects_from_file

    root = copy_built(built_house[0], tmp_path / "ws")
    c = make_client(root)
    start = c.get(f"/api/scenes/{HOUSE}/objects").json()
    assert start["source"] == "goals"
    upper = [o for o in start["objects"] if o.get("floor") == 1]
    assert upper and all("floor" not in o for o in start["objects"] if o not in upper)  # floor 0 is not written
    assert {r["id"]: r.get("floor", 0) for r in start["rooms"]}["bedroom_1"] == 1
    new = {"key": "rug_9", "cls": "rug", "instance_id": 0, "room": "bedroom_1", "floor": 1,
           "footprint": [[3.0, 6.0], [3.5, 6.0], [3.5, 6.5], [3.0, 6.5]], "mass_center": [3.25, 6.25]}
    body = {"path": "objects/house.yaml", "rooms": start["rooms"], "objects": [*start["objects"], new]}
    assert c.post(f"/api/scenes/{HOUSE}/objects/validate", json=body, **W).json()["ok"]
    saved = c.put(f"/api/scenes/{HOUSE}/objects", json=body, **W)
    assert saved.status_code == 200, saved.text
    written = yaml.safe_load((root / "objects" / "house.yaml").read_text())
    assert next(o for o in written["objects"] if o["key"] == "rug_9")["floor"] == 1
    objset = objects_from_file(root / "objects" / "house.yaml", HOUSE)
    assert {o.key: o.floor for o in objset.objects}["rug_9"] == 1
    assert sum(o.floor == 1 for o in objset.objects) == len(upper) + 1
    # an object or room on a floor the house does not have: refused, nothing written
    before = (root / "objects" / "house.yaml").read_text()
    for bad in ({**body, "objects": [*start["objects"], {**new, "floor": 3}]},
                {**body, "rooms": [*start["rooms"], {"id": "attic_1", "type": "attic", "floor": 2,
                                                       "polygon": [[0, 0], [1, 0], [1, 1]]}]}):
        r = c.post(f"/api/scenes/{HOUSE}/objects/validate", json=bad, **W)
        assert r.status_code == 422 and r.json()["field"] == "floor", r.text
        assert ("rug_9 (floor 3): " if bad["rooms"] is start["rooms"] else "room attic_1 (floor 2): ") \
            + "scene house has 2 floors: 0 (floor 0, 0.00 m), 1 (floor 1," in r.json()["error"]
        refused(c.put(f"/api/scenes/{HOUSE}/objects", json=bad, **W), 422, "floor", "scene house has 2 floors")
    assert (root / "objects" / "house.yaml").read_text() == before


def test_a_goal_of_objects_on_two_floors_is_refused(client, summary):
    r = client.get(f"/api/scenes/{HOUSE}/goals")
    doc = r.json()["document"]
    i, upper = next((i, g) for i, g in enumerate(doc["goals"]) if summary["goals"][i]["floor"] == 1)
    lower = next(o["key"] for o in summary["objects"] if o["floor"] == 0)
    upper["objects"] = [*upper["objects"], lower]
    body = refused(client.post(f"/api/scenes/{HOUSE}/goals/validate", json={"document": doc}, **W), 422,
                   f"goals[{i}].objects", f"{lower} (floor 0) lie on different floors; a goal's objects lie on one floor")
    assert body["field"] == f"goals[{i}].objects"


def test_a_saved_edit_rebuilds_the_house_and_its_goals_keep_their_floors(built_house, tmp_path):
    """The save transaction on a building: goals and routes rebuilt per floor; the renamed goal upstairs keeps its
    floor and its procedural feedback, which the preview from the recording's start still says."""
    root = copy_built(built_house[0], tmp_path / "ws")
    c = make_client(root)
    r = c.get(f"/api/scenes/{HOUSE}/goals")
    doc, etag = r.json()["document"], r.headers["etag"].strip('"')
    before = c.get(f"/api/scenes/{HOUSE}").json()["goals"]
    i = next(i for i, g in enumerate(before) if g["floor"] == 1)
    doc["goals"][i]["name"] = "Grandma's reading chair"
    saved = c.put(f"/api/scenes/{HOUSE}/goals", json={"document": doc}, headers={"Origin": ORIGIN, "If-Match": etag})
    assert saved.status_code == 200, saved.text
    assert [o["stage"] for o in saved.json()["outcomes"]] == ["goals", "routes"]
    after = c.get(f"/api/scenes/{HOUSE}").json()
    goal = after["goals"][i]
    assert goal["name"] == "Grandma's reading chair" and goal["floor"] == 1 and goal["id"] == before[i]["id"]
    stored = c.get(f"/api/scenes/{HOUSE}/goals").json()["document"]["goals"][i]["feedback"]["procedural"]
    preview = c.get(f"/api/scenes/{HOUSE}/route", params={"objects": ",".join(goal["objects"])}).json()
    assert stored and preview["text"] == stored and "go up the stairs" in stored


def test_a_single_floor_scene_is_floor_0(shared_root):
    c = make_client(shared_root)
    s = c.get(f"/api/scenes/{SCENE}").json()
    assert [f["id"] for f in s["floors"]] == [0] and s["stairs"] == []
    assert all(len(p) == 3 for p in s["trajectory"])  # no floor value in a single-floor scene's poses
    assert all(o["floor"] == 0 for o in s["objects"]) and all(g["floor"] == 0 for g in s["goals"])
    assert all([leg["floor"] for leg in r["legs"]] == [0] and r["legs"][0]["path"] == r["path"] for r in s["routes"])
    refused(c.get(f"/api/scenes/{SCENE}/layers/color.png", params={"floor": 1}), 400,
            f"floor 1: scene {SCENE} has 1 floor: 0 (floor 0,")
    goal = s["goals"][0]
    body = c.get(f"/api/scenes/{SCENE}/route", params={"objects": ",".join(goal["objects"])}).json()
    assert body["start_floor"] == body["goal_floor"] == 0 and body["stairs"] == []
    if body["reachable"]:
        assert body["legs"] == [{"floor": 0, "path": body["path"]}]
