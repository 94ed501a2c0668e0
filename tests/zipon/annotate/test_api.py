"""Every endpoint of the annotation server on the tiny built scene: good input answers what the scene holds, bad
input is refused with its status, the field and why, and leaves everything built as it was."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from tests.zipon.annotate.conftest import ORIGIN, SCENE, scene_summary, make_client, png, refused, tree_state

W = {"headers": {"Origin": ORIGIN}}  # what the page sends on every write


@pytest.fixture(scope="module")
def client(shared_root):
    return make_client(shared_root)


@pytest.fixture(scope="module")
def summary(client):
    return scene_summary(client, SCENE)


def goals_doc(client) -> tuple[dict, str]:
    r = client.get(f"/api/scenes/{SCENE}/goals")
    assert r.status_code == 200
    return r.json()["document"], r.headers["etag"].strip('"')






# ----------------------------------------------------------------------------- reading the scene

def test_feedback_kinds_are_the_registry_with_their_forms_and_defaults(client):
    """The page makes its feedback fields from this answer: a kind added to the registry appears on the page."""
    from pipeline.goals.feedback import FEEDBACK_KINDS

    kinds = client.get("/api/feedback-kinds").json()["kinds"]
    assert [k["name"] for k in kinds] == sorted(FEEDBACK_KINDS) == list(goals_doc(client)[0]["goals"][0]["feedback"])
    by_name = {k["name"]: k for k in kinds}
    assert {n: (k["form"], k["default"]) for n, k in by_name.items()} == {
        "corrective": ("key_lines", {}), "descriptive": ("text", ""), "landmark": ("text", ""),
        "procedural": ("optional_text", None)}
    assert by_name["descriptive"]["new_goal"] == "It is a {class}." and by_name["landmark"]["new_goal"] == ""
    assert by_name["procedural"]["description"].startswith("route in words")


def test_page_and_scene_list(client):
    page = client.get("/")
    assert page.status_code == 200 and "<canvas id=\"map\">" in page.text and "/static/app.js" in page.text
    assert "http" not in page.text.replace(ORIGIN, "")  # nothing loaded from elsewhere
    js = client.get("/static/app.js")
    assert js.status_code == 200 and "textContent" in js.text and "innerHTML" not in js.text
    body = client.get("/api/scenes").json()
    assert body["default"] == SCENE
    [s] = body["scenes"]
    assert s["name"] == SCENE and s["locked"] is None and {"recon", "goals", "routes", "vlmap"} <= set(s["built"])


def test_scene_summary_matches_the_built_artifacts(shared_root, summary):
    from pipeline.goals.store import Goals
    from pipeline.recon import Recon
    from pipeline.routes.store import Routes

    art = shared_root / "data" / "artifacts" / SCENE
    recon, goals, routes = Recon(art / "recon.zarr"), Goals(art / "goals.zarr"), Routes(art / "routes.zarr")
    assert summary["grid"]["rows"] == recon.grid.rows and summary["grid"]["cell_size_m"] == recon.grid.cell_size_m
    assert [g["name"] for g in summary["goals"]] == [g.name for g in goals.goals]  # zipon render's numbering
    assert [g["number"] for g in summary["goals"]] == list(range(1, len(goals.goals) + 1))
    assert sorted(o["key"] for o in summary["objects"]) == sorted(goals.objects)
    assert len(summary["routes"]) == len(routes.episodes) > 0
    assert all(len(r["path"]) >= 2 for r in summary["routes"])
    assert 2 <= len(summary["trajectory"]) <= len(recon.poses)
    assert summary["ground_truth"] is True and {"color", "navigable", "rooms"} <= set(summary["layers"])
    assert all(len(r["polygon"]) >= 3 for r in summary["rooms"])


def test_unknown_scene(client):
    refused(client.get("/api/scenes/nowhere"), 404, "unknown scene 'nowhere'", "'tiny'")
    refused(client.get("/api/scenes/nowhere/goals"), 404, "unknown scene")


@pytest.mark.parametrize("name", ["color", "height", "occupancy", "navigable", "rooms"])
def test_layers_are_one_pixel_per_cell(client, summary, name):
    img = png(client.get(f"/api/scenes/{SCENE}/layers/{name}.png"))
    assert img.shape == (summary["grid"]["rows"], summary["grid"]["cols"], 4)
    assert 0 < (img[..., 3] > 0).sum() < img.shape[0] * img.shape[1] + 1


def test_unknown_layer(client):
    refused(client.get(f"/api/scenes/{SCENE}/layers/feelings.png"), 422, "unknown layer 'feelings'", "layer")


@pytest.mark.parametrize("name", ["color", "height", "navigable", "rooms"])
def test_a_layer_window_is_the_floor_picture_there_at_the_resolution_asked(client, summary, name, monkeypatch):
    from tests.fixtures.tiled_maps import chunk_reads

    g = summary["grid"]
    whole = png(client.get(f"/api/scenes/{SCENE}/layers/{name}.png"))
    x0, x1, y0, y1 = summary["grid"]["observed_xy"]
    box = f"{x0:.3f},{y0:.3f},{x0 + 2:.3f},{y0 + 1.5:.3f}"  # a 2 m x 1.5 m corner: 40 x 30 cells, full resolution
    with chunk_reads(monkeypatch) as reads:
        r = client.get(f"/api/scenes/{SCENE}/layers/{name}.png", params={"region": box, "px": 800})
    img = png(r)
    assert img.shape == (30, 40, 4) and r.headers["x-zipon-stride"] == "1"
    ex0, ex1, ey0, ey1 = map(float, r.headers["x-zipon-extent"].split(","))
    c0, r0 = round((ex0 - g["origin_xy"][0]) / g["cell_size_m"]), round((g["origin_xy"][1] - ey1) / g["cell_size_m"])
    assert (ex1 - ex0, ey1 - ey0) == pytest.approx((2.0, 1.5), abs=0.051)
    assert np.array_equal(img, whole[r0:r0 + 30, c0:c0 + 40])  # the same cells as the floor's picture
    assert sum(reads.values()) <= 4 * 3  # at most 2 x 2 of the 128-cell tiles (a grid or two each), never all
    # the floor at a zoom that fits 150 px: every k-th cell
    fit = client.get(f"/api/scenes/{SCENE}/layers/{name}.png", params={"region": f"{x0},{y0},{x1},{y1}",
                                                                        "px": 150})
    k = int(fit.headers["x-zipon-stride"])
    small = png(fit)
    assert k > 1 and max(small.shape[:2]) <= 150
    fx0, _, _, fy1 = map(float, fit.headers["x-zipon-extent"].split(","))
    fc0, fr0 = round((fx0 - g["origin_xy"][0]) / g["cell_size_m"]), round((g["origin_xy"][1] - fy1) / g["cell_size_m"])
    assert np.array_equal(small, whole[fr0::k, fc0::k][:small.shape[0], :small.shape[1]])


@pytest.mark.parametrize("params, status, words", [
    ({"region": "1,2,0,3"}, 422, ("x runs from 1 to 0: inverted", "region")),
    ({"region": "0,2,1,2"}, 422, ("y runs from 2 to 2: empty", "region")),
    ({"region": "1000,1000,1001,1001"}, 422, ("lies outside the floor's grid", "region")),
    ({"region": "a,b,c,d"}, 422, ("region",)),
    ({"px": "0"}, 400, ("px=0 is outside 16..16384", "px")),
])
def test_a_bad_layer_window_is_refused_naming_the_parameter(client, params, status, words):
    refused(client.get(f"/api/scenes/{SCENE}/layers/color.png", params=params), status, *words)


def test_frames_that_saw_a_place(client, summary):
    from pipeline.frames import FrameStore

    goal = summary["goals"][0]
    x, y = goal["mass_center"]
    body = client.get(f"/api/scenes/{SCENE}/seen", params={"x": x, "y": y}).json()
    assert body["frames"], body
    distances = [f["distance_m"] for f in body["frames"]]
    assert distances == sorted(distances)
    frames = FrameStore(client.app.state.workbench.workspace.artifact("frames", SCENE))
    f = body["frames"][0]
    img = png(client.get(f"/api/scenes/{SCENE}/frames/{f['frame']}.png", params={"u": f["pixel"][0],
                                                                                "v": f["pixel"][1]}))
    assert img.shape == (frames.intrinsics.height, frames.intrinsics.width, 3)
    changed = np.any(img != frames.group["rgb"][f["frame"]], axis=-1)  # the place is ringed, nothing else drawn
    rows, cols = np.nonzero(changed)
    assert rows.size and np.hypot(rows - f["pixel"][1], cols - f["pixel"][0]).max() <= 2 * max(3, img.shape[1] // 40)


@pytest.mark.parametrize("query, status, words", [
    ({"x": "nan", "y": 1}, 400, ["'nan' is not finite", "x"]),
    ({"x": "1e999", "y": 1}, 400, ["not finite"]),
    ({"x": "east", "y": 1}, 400, ["'east' is not a number"]),
    ({"y": 1}, 400, ["missing query parameter x"]),
    ({"x": 500, "y": 1}, 422, ["is off the map"]),
])
def test_seen_bad_points(client, query, status, words):
    refused(client.get(f"/api/scenes/{SCENE}/seen", params=query), status, *words)


def test_frame_out_of_range(client):
    refused(client.get(f"/api/scenes/{SCENE}/frames/99999.png"), 422, "frame 99999 is not in", "frame")


def test_map_proposals_are_footprints_with_scores(client, summary):
    cls = summary["objects"][0]["cls"]
    r = client.get(f"/api/scenes/{SCENE}/propose", params={"map": "vlmap", "text": cls})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["heatmap"].startswith("data:image/png;base64,") and body["proposals"], body["text"]
    objects = [o for o in summary["objects"] if o["cls"] == cls]
    for p in body["proposals"]:
        assert len(p["footprint"]) >= 3 and 0 < p["score"] <= 1 and p["area_m2"] > 0
    # the best proposal lies on an object of that class (the oracle encoder scores the ground truth)
    best = body["proposals"][0]["center_xy"]
    assert min(math.dist(best, o["mass_center"]) for o in objects) < 1.0


@pytest.mark.parametrize("query, status, words", [
    ({"map": "vlmap", "text": ""}, 400, ["give the class or phrase"]),
    ({"map": "vlmap", "text": "x" * 201}, 400, ["1 to 200 characters"]),
    ({"map": "octomap", "text": "chair"}, 400, ["map 'octomap': choose vlmap or cfmap"]),
])
def test_proposals_bad_input(client, query, status, words):
    refused(client.get(f"/api/scenes/{SCENE}/propose", params=query), status, *words)


def test_route_preview_is_procedural_feedback(client, summary):
    ep = summary["routes"][0]
    goal = next(g for g in summary["goals"] if g["id"] == ep["goal_id"])
    x, y, yaw = ep["start"]
    body = client.get(f"/api/scenes/{SCENE}/route", params={"x": x, "y": y, "yaw_deg": math.degrees(yaw),
                                                             "objects": ",".join(goal["objects"])}).json()
    assert body["reachable"] and body["text"] and len(body["path"]) >= 2
    assert math.dist(body["path"][0], (x, y)) < 0.2
    refused(client.get(f"/api/scenes/{SCENE}/route", params={"x": x, "y": y, "objects": "sofa_99"}), 422,
            "unknown objects ['sofa_99']")
    refused(client.get(f"/api/scenes/{SCENE}/route", params={"x": "inf", "y": y, "objects": goal["objects"][0]}),
            400, "not finite")


def test_route_preview_from_the_recorded_start_says_every_goals_stored_procedural_feedback(client, shared_root):
    """The workbench previews the route the goals stage stores (one pipeline.nav.region.route_to_goal): from the
    recording's start, every goal's preview text is its stored procedural feedback, word for word."""
    from pipeline.goals.store import Goals

    stored_goals = Goals(next(shared_root.rglob(f"{SCENE}/goals.zarr"))).goals
    said = 0
    for goal in stored_goals:
        body = client.get(f"/api/scenes/{SCENE}/route", params={"objects": ",".join(goal.object_keys)}).json()
        stored = goal.feedback["procedural"]
        if stored is None:  # unreachable, or the start already lies in the goal
            assert not body["reachable"] or body["text"] == "", (goal.id, body)
            continue
        assert body["reachable"] and body["text"] == stored, (goal.id, body["text"], stored)
        said += 1
    assert said >= 3


# ----------------------------------------------------------------------------- goals: validation

def test_goals_document_and_its_etag(client, shared_root):
    from pipeline.goals.schema import document_digest
    from pipeline.goals.store import Goals

    doc, etag = goals_doc(client)
    goals = Goals(shared_root / "data" / "artifacts" / SCENE / "goals.zarr")
    assert etag == document_digest(goals.document) and doc["goals"][0]["name"] == goals.goals[0].name


def test_validate_a_good_edit(client):
    doc, _ = goals_doc(client)
    doc["goals"][0]["feedback"]["landmark"] = "It is near the window."
    body = client.post(f"/api/scenes/{SCENE}/goals/validate", json={"document": doc}, **W).json()
    assert body["ok"] is True and body["warnings"] == []


def test_descriptive_text_is_checked_against_the_object(client, summary):
    doc, _ = goals_doc(client)
    objects = {o["key"]: o for o in summary["objects"]}
    i, g = next((i, g) for i, g in enumerate(doc["goals"]) if objects[g["objects"][0]]["color_name"])
    have = objects[g["objects"][0]]["color_name"]
    other = next(o["color_name"] for o in summary["objects"] if o["color_name"] and o["color_name"] != have)
    doc["goals"][i]["feedback"]["descriptive"] = f"It is a {other} thing."
    body = client.post(f"/api/scenes/{SCENE}/goals/validate", json={"document": doc}, **W).json()
    assert body["ok"] is True
    assert {"field": f"goals[{i}].feedback.descriptive",
            "message": f"says {other} but {g['objects'][0]}'s colour is {have}"} in body["warnings"]


def _bad_edits():
    def dup(d):
        d["goals"][1]["name"] = d["goals"][0]["name"].upper()

    def unknown_object(d):
        d["goals"][0]["objects"].append("sofa_99")

    def bad_type(d):
        d["goals"][0]["type"] = "huge"

    def wrong_scene(d):
        d["scene"] = "elsewhere"

    def polygon_in_goal(d):
        next(iter(d["objects"].values()))["position_xy"] = [1.0]

    def empty_name(d):
        d["goals"][0]["name"] = ""

    return [(dup, "not unique", None), (unknown_object, "sofa_99", None), (bad_type, "'big', 'small' or 'ambiguous'", "goals[0].type"),
            (wrong_scene, "'elsewhere'", "scene"), (polygon_in_goal, "position_xy", None),
            (empty_name, "goals[0].name", "goals[0].name")]


@pytest.mark.parametrize("edit, words, field", _bad_edits(), ids=lambda v: getattr(v, "__name__", None))
def test_invalid_edits_are_named_and_nothing_changes(client, shared_root, edit, words, field):
    before = tree_state(shared_root)
    doc, etag = goals_doc(client)
    edit(doc)
    r = client.post(f"/api/scenes/{SCENE}/goals/validate", json={"document": doc}, **W)
    body = refused(r, 422, words)
    assert body["ok"] is False and body["error"].startswith("file the edited goals")
    if field:
        assert body["field"] == field
    saved = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc}, headers={"Origin": ORIGIN,
                                                                                     "If-Match": f'"{etag}"'})
    refused(saved, 422, words)
    assert tree_state(shared_root) == before


def test_nan_and_non_json_bodies(client, shared_root):
    before = tree_state(shared_root)
    doc, _ = goals_doc(client)
    text = json.dumps({"document": doc}).replace(json.dumps(next(iter(doc["objects"].values()))["position_xy"]),
                                                 "[NaN, 1.0]", 1)
    r = client.post(f"/api/scenes/{SCENE}/goals/validate", content=text, headers={"Origin": ORIGIN,
                                                                                  "Content-Type": "application/json"})
    refused(r, 400, "NaN is not a number")
    refused(client.post(f"/api/scenes/{SCENE}/goals/validate", content="{goals:", **W), 400, "the body is not JSON")
    refused(client.post(f"/api/scenes/{SCENE}/goals/validate", json=[1, 2], **W), 400, "must be a JSON object")
    refused(client.post(f"/api/scenes/{SCENE}/goals/validate", json={"goals": []}, **W), 400, "needs a 'document'")
    assert tree_state(shared_root) == before


# ----------------------------------------------------------------------------- safety

def test_writes_need_the_pages_own_origin(client, shared_root):
    before = tree_state(shared_root)
    doc, etag = goals_doc(client)
    for headers in ({}, {"Origin": "http://evil.example"}, {"Origin": "null"}):
        r = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc}, headers={**headers,
                                                                                     "If-Match": f'"{etag}"'})
        refused(r, 403, "cross-origin write refused")
    refused(client.put(f"/api/scenes/{SCENE}/objects", json={"path": "objects/x.yaml", "objects": []},
                       headers={"Origin": "http://evil.example"}), 403, "cross-origin")
    assert tree_state(shared_root) == before


def test_oversized_body(client, shared_root):
    before = tree_state(shared_root)
    r = client.post(f"/api/scenes/{SCENE}/goals/validate", content=b"{" + b" " * 2_100_000 + b"}", **W)
    refused(r, 413, "over the 2,000,000-byte limit", "body")
    assert tree_state(shared_root) == before


def test_stale_or_missing_etag_saves_nothing(client, shared_root):
    before = tree_state(shared_root)
    doc, etag = goals_doc(client)
    doc["goals"][0]["feedback"]["landmark"] = "It is near the window."
    r = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc},
                   headers={"Origin": ORIGIN, "If-Match": '"0123456789ab"'})
    body = refused(r, 412, "the goals changed since you opened them")
    assert body["current"] == etag
    refused(client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc}, **W), 428, "If-Match is required")
    assert tree_state(shared_root) == before


def test_a_scene_being_rebuilt_is_refused_naming_the_holder(own_root):
    import os

    from pipeline.engine.locks import holder_record

    client = make_client(own_root)
    doc, etag = goals_doc(client)
    lock = own_root / "data" / "artifacts" / SCENE / ".goals.lock"
    lock.write_text(holder_record())  # a live holder: this process
    before = tree_state(own_root)
    r = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc}, headers={"Origin": ORIGIN,
                                                                                 "If-Match": f'"{etag}"'})
    refused(r, 409, f"scene {SCENE} is being rebuilt by another zipon run: pid {os.getpid()}", str(lock))
    assert client.get("/api/scenes").json()["scenes"][0]["locked"].startswith(f"pid {os.getpid()}")
    assert tree_state(own_root) == before


def test_token_and_host_checks(shared_root):
    client = make_client(shared_root, token="s3cret", allowed_hosts=None)
    refused(client.get("/api/scenes"), 403, "a token is needed")
    refused(client.get("/", params={"token": "wrong"}), 403, "a token is needed")
    page = client.get("/", params={"token": "s3cret"})
    assert page.status_code == 200 and client.cookies.get("zipon_annotate_token") == "s3cret"
    assert client.get("/api/scenes").status_code == 200  # the cookie carries it from then on
    local = make_client(shared_root)
    refused(local.get("/api/scenes", headers={"Host": "evil.example:8765"}), 403, "host 'evil.example' is not served")


@pytest.mark.parametrize("path", ["/static/../params.yaml", "/static/%2e%2e/params.yaml", "/static/..%2fparams.yaml"])
def test_static_files_stay_in_the_package(client, path):
    r = client.get(path)
    assert r.status_code == 404 and "scenes:" not in r.text


# ----------------------------------------------------------------------------- objects files

def test_objects_start_from_the_built_objects(client, summary):
    body = client.get(f"/api/scenes/{SCENE}/objects").json()
    assert body["source"] == "goals" and body["path"] == f"objects/{SCENE}.yaml"
    assert sorted(o["key"] for o in body["objects"]) == sorted(o["key"] for o in summary["objects"])
    assert all(len(r["polygon"]) >= 3 for r in body["rooms"])


@pytest.mark.parametrize("change, words", [
    (lambda o: o["objects"][0].update(footprint=[[0, 0], [1, 0]]), ["objects[0].footprint"]),
    (lambda o: o["objects"][0].update(footprint=[[0, 0], [1, "x"], [1, 1]]), ["objects[0].footprint"]),
    (lambda o: o["objects"][1].update(key=o["objects"][0]["key"]), ["duplicate object keys"]),
    (lambda o: o["objects"][0].update(room="attic_9"), ["room 'attic_9' is not one of"]),
])
def test_malformed_objects_are_refused(client, shared_root, change, words):
    before = tree_state(shared_root)
    body = client.get(f"/api/scenes/{SCENE}/objects").json()
    change(body)
    refused(client.post(f"/api/scenes/{SCENE}/objects/validate", json=body, **W), 422, *words)
    refused(client.put(f"/api/scenes/{SCENE}/objects", json=body, **W), 422, *words)
    assert tree_state(shared_root) == before


@pytest.mark.parametrize("path, words", [
    ("../outside.yaml", ["leaves the workspace"]),
    ("objects/../../outside.yaml", ["leaves the workspace"]),
    ("/etc/objects.yaml", ["is not a relative path"]),
    ("objects/notes.txt", ["is not a .yaml, .yml or .json file"]),
    ("", ["is not a relative path"]),
])
def test_objects_file_paths_stay_in_the_workspace(client, shared_root, path, words):
    before = tree_state(shared_root)
    body = client.get(f"/api/scenes/{SCENE}/objects").json()
    refused(client.put(f"/api/scenes/{SCENE}/objects", json={**body, "path": path}, **W), 400, *words)
    assert tree_state(shared_root) == before and not (shared_root.parent / "outside.yaml").exists()


def test_saved_objects_file_is_what_goals_objects_file_reads(own_root):
    from pipeline.goals.objects import objects_from_file

    client = make_client(own_root)
    body = client.get(f"/api/scenes/{SCENE}/objects").json()
    body["objects"].append({"key": "chair_99", "cls": "chair", "instance_id": 0, "footprint": [[1, 1], [1.5, 1],
                                                                                              [1.5, 1.5]],
                            "mass_center": [1.33, 1.17]})
    r = client.put(f"/api/scenes/{SCENE}/objects", json={**body, "path": "objects/mine.yaml"}, **W)
    assert r.status_code == 200, r.text
    assert r.json()["next"] == f"in params.yaml: goals: {{objects: file, objects_files: {{{SCENE}: objects/mine.yaml}}}}"
    objset = objects_from_file(own_root / "objects" / "mine.yaml", SCENE)
    assert [o.key for o in objset.objects] == [o["key"] for o in body["objects"]]
    assert objset.by_key()["chair_99"].footprint == [(1, 1), (1.5, 1), (1.5, 1.5)]


# ----------------------------------------------------------------------------- saving, history, restore

def test_save_rebuilds_then_history_diffs_and_restores(own_root):
    from pipeline.engine.manifest import Manifest

    client = make_client(own_root)
    routes_before = Manifest.read(own_root / "manifests" / SCENE / "routes.json")
    doc, etag = goals_doc(client)
    doc["goals"][0]["feedback"]["landmark"] = "It is near the window."
    first = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc},
                       headers={"Origin": ORIGIN, "If-Match": f'"{etag}"'})
    assert first.status_code == 200, first.text
    saved = first.json()
    assert [o["stage"] for o in saved["outcomes"]] == ["goals", "routes"]
    assert all(o["status"] == "ran" for o in saved["outcomes"])
    assert first.headers["etag"].strip('"') == saved["etag"] != etag
    params = yaml.safe_load((own_root / "params.yaml").read_text())
    assert params["goals"]["edits"][SCENE] == saved["saved"] and (own_root / saved["saved"]).is_file()
    routes_after = Manifest.read(own_root / "manifests" / SCENE / "routes.json")
    assert routes_after.inputs != routes_before.inputs  # routes.zarr was rebuilt from the edited goals
    # the old ETag is stale now
    refused(client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc},
                       headers={"Origin": ORIGIN, "If-Match": f'"{etag}"'}), 412, "changed since you opened them")
    doc2, etag2 = goals_doc(client)
    assert doc2["goals"][0]["feedback"]["landmark"] == "It is near the window."
    doc2["goals"][0]["feedback"]["landmark"] = "It is by the door."
    second = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc2},
                        headers={"Origin": ORIGIN, "If-Match": f'"{etag2}"'})
    assert second.status_code == 200, second.text
    edits = client.get(f"/api/scenes/{SCENE}/history").json()["edits"]
    assert [e["digest"] for e in edits] == [second.json()["digest"], saved["digest"]]
    assert [e["current"] for e in edits] == [True, False]
    shown = client.get(f"/api/scenes/{SCENE}/history/{saved['digest']}").json()
    assert "-  feedback:" not in shown["diff"]
    assert any(line.startswith("-") and "by the door" in line for line in shown["diff"].splitlines())
    assert any(line.startswith("+") and "near the window" in line for line in shown["diff"].splitlines())
    back = client.post(f"/api/scenes/{SCENE}/history/{saved['digest']}/restore", json={},
                       headers={"Origin": ORIGIN, "If-Match": f'"{second.json()["etag"]}"'})
    assert back.status_code == 200, back.text
    assert yaml.safe_load((own_root / "params.yaml").read_text())["goals"]["edits"][SCENE] == saved["saved"]
    assert goals_doc(client)[0]["goals"][0]["feedback"]["landmark"] == "It is near the window."


def test_history_bad_digests(client):
    refused(client.get(f"/api/scenes/{SCENE}/history/..secret"), 400, "is not an edit digest")
    refused(client.get(f"/api/scenes/{SCENE}/history/abcdef123456"), 404, "no stored edit abcdef123456")
    assert client.get(f"/api/scenes/{SCENE}/history").json() == {"edits": []}


def test_a_failed_rebuild_is_reported_and_undone(own_root, monkeypatch):
    import stages.routes
    from pipeline.errors import StageError

    def routes_fail(ctx):
        raise StageError("no route reaches the edited goal")

    monkeypatch.setattr(stages.routes, "run", routes_fail)
    client = make_client(own_root)
    params_text = (own_root / "params.yaml").read_bytes()
    doc, etag = goals_doc(client)
    doc["goals"][0]["feedback"]["landmark"] = "It is near the window."
    r = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc},
                   headers={"Origin": ORIGIN, "If-Match": f'"{etag}"'})
    body = refused(r, 422, "not saved", "no route reaches the edited goal", "params.yaml unchanged")
    assert body["restored"] == ["goals"]
    assert (own_root / "params.yaml").read_bytes() == params_text and not (own_root / "goals_edits").exists()
    assert goals_doc(client)[1] == etag  # goals rebuilt without the edit: the same document


# ----------------------------------------------------------------------------- play as the user

def test_play_refuses_what_it_cannot_play(client, summary, shared_root):
    before = tree_state(shared_root)
    goal = summary["goals"][0]["id"]
    url = f"/api/scenes/{SCENE}/play"
    refused(client.post(url, json={"method": "telepathy", "goal": goal}, **W), 400, "unknown agent 'telepathy'")
    refused(client.post(url, json={"method": "vlmap", "goal": "sofa_99"}, **W), 422, "no goal 'sofa_99'")
    refused(client.post(url, json={"method": "vlmap", "goal": goal, "seed": -1}, **W), 400, "seed -1")
    refused(client.post(url, json={"method": "vlmap", "goal": goal, "seed": True}, **W), 400, "seed True")
    refused(client.post(url, json={"method": "vlmap", "goal": goal}), 403, "cross-origin write refused")
    refused(client.get(f"{url}/abc123"), 404, "no episode 'abc123'")
    refused(client.post(f"{url}/abc123/reply", json={"text": "No."}, **W), 404, "no episode 'abc123'")
    assert tree_state(shared_root) == before
    assert [a["name"] for a in client.get("/api/agents").json()["agents"]][:2] == ["human", "cow"]


def test_play_an_episode_answering_as_the_user(own_root, summary):
    client = make_client(own_root)
    goal = next((g for g in summary["goals"] if g["type"] == "ambiguous"), summary["goals"][0])
    state = client.post(f"/api/scenes/{SCENE}/play", json={"method": "vlmap", "goal": goal["id"]}, **W).json()
    replies = 0
    while state["status"] == "waiting" and replies < 10:
        assert state["question"]["text"] and state["question"]["suggestion"]
        refused(client.post(f"/api/scenes/{SCENE}/play/{state['id']}/reply", json={"text": "  "}, **W), 400,
                "1 to 2000 characters")
        state = client.post(f"/api/scenes/{SCENE}/play/{state['id']}/reply", json={"text": "No, it is by the TV."},
                            **W).json()
        replies += 1
    assert state["status"] == "done", state
    refused(client.post(f"/api/scenes/{SCENE}/play/{state['id']}/reply", json={"text": "hello"}, **W), 422,
            "not waiting for a reply")
    assert png(client.get(f"/api/scenes/{SCENE}/play/{state['id']}/ego.png")).ndim == 3
    [record] = [json.loads(line) for line in (own_root / "data" / "eval" / "human" / f"{SCENE}.episodes.jsonl")
                .read_text().splitlines()]
    assert record["feedback"] == "human" and record["goal"] == goal["id"]
    said = [d["text"] for d in record["log"]["dialogue"] if d["speaker"] == "user"]
    assert said[:replies] == ["No, it is by the TV."] * replies
    assert state["result"]["talk_turns"] == record["talk_turns"] == replies + record["success"]
    # zipon eval reports the person's episodes as their own feedback setting, beside simulated ones
    from zipon.cli import main

    args = ["-q", "-p", str(own_root / "params.yaml"), "eval", "-s", SCENE, "-m", "vlmap", "-f", "human",
            "-f", "yesno", "--seeds", "1", "--out", str(own_root / "ev")]
    assert main(args) == 0
    results = json.loads((own_root / "ev" / "results.json").read_text())
    assert results["overall"]["vlmap"]["human"]["episodes"] == 1
    assert results["overall"]["vlmap"]["human"]["SR"] == 100.0 * record["success"]
    assert results["overall"]["vlmap"]["yesno"]["episodes"] >= 1
    assert "human" in (own_root / "ev" / "report.html").read_text()


def test_eval_of_human_feedback_without_played_episodes_says_where_to_play(own_root, capsys):
    from zipon.cli import main

    code = main(["-p", str(own_root / "params.yaml"), "eval", "-s", SCENE, "-m", "cow", "-f", "human",
                 "--out", str(own_root / "ev2")])
    err = " ".join(capsys.readouterr().err.split())
    assert code == 1 and "--feedback human: no human-answered episodes of ['cow'] stored for" in err
    assert "zipon annotate" in err and not (own_root / "ev2").exists()


def test_warm_reads_the_first_scene_before_the_page_asks(shared_root):
    wb = make_client(shared_root).app.state.workbench
    assert wb._views == {}
    wb.warm()
    view = wb._views[SCENE]
    # the summary, and what the layers' pictures share (the pictures are of the windows the page will ask for)
    assert {("height_top", 0), "recon", "observed_rc"} <= set(view._cache)
