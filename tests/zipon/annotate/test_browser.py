"""The annotation page in a real headless browser (Debian's chromium driven by playwright): open the scene, look at
the frames that saw an object, accept a map proposal, draw a footprint, save the objects file, create a goal with
descriptive and procedural feedback and save it (goals export then holds it and routes.zarr was rebuilt), see an
invalid edit refused inline with nothing saved, play one episode as the user; on a two-storey house, switch floors,
preview a route over the stairs and place an object upstairs. A screenshot of each state is written
under the test's tmp folder (pytest removes a passing test's folder: keep them with
``-o tmp_path_retention_policy=all -s``, which also prints where they are).

Playwright over Selenium: one pip package (the Python client and its driver; its own browser downloads are never
used: ``executable_path`` points at Debian's chromium), auto-waiting locators and no chromedriver version to match.
"""

from __future__ import annotations

import json
import shutil
from contextlib import contextmanager

import pytest
import yaml

from tests.zipon.annotate.conftest import SCENE, copy_built, serving

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@contextmanager
def chromium_page():
    """A page of Debian's chromium, headless; no page error may happen while it is open."""
    if not shutil.which(CHROMIUM) and not shutil.os.path.exists(CHROMIUM):
        pytest.skip("Debian's chromium is not installed (setup.sh installs it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        pg = browser.new_page(viewport={"width": 1400, "height": 850})
        errors = []
        pg.on("pageerror", lambda e: errors.append(str(e)))
        yield pg
        browser.close()
        assert errors == [], errors


@pytest.fixture
def page(served):
    with chromium_page() as pg:
        yield pg


def at(pg, x: float, y: float) -> tuple[float, float]:
    """The page's pixel of world point (x, y) metres."""
    u, v = pg.evaluate(f"() => toScreen({x}, {y})")
    box = pg.locator("#map").bounding_box()
    return box["x"] + u, box["y"] + v


def goals_export(root) -> dict:
    from zipon.cli import main

    out = root / "exported.yaml"
    assert main(["-q", "-p", str(root / "params.yaml"), "goals", "export", SCENE, "-o", str(out)]) == 0
    return yaml.safe_load(out.read_text())


def opened(pg, served, tmp_path):
    """The page ``pg`` on the served scene, loaded: ``(pg, the workspace root, a folder for screenshots)``."""
    url, root = served
    shots = tmp_path / "screenshots"
    shots.mkdir()
    pg.goto(url)
    pg.wait_for_selector(f"body[data-ready={SCENE}]")
    return pg, root, shots


@pytest.mark.slow
def test_the_page_end_to_end(page, served, tmp_path):
    from pipeline.goals.objects import objects_from_file
    from pipeline.engine.manifest import Manifest

    pg, root, shots = opened(page, served, tmp_path)
    data = pg.evaluate("() => S.data")
    assert pg.locator("#goal-list li").count() == len(data["goals"]) > 0
    pg.screenshot(path=str(shots / "1_scene.png"))

    # the frames that saw an object
    obj = next(o for o in data["objects"] if o["cls"] == "couch") if any(
        o["cls"] == "couch" for o in data["objects"]) else data["objects"][0]
    pg.mouse.click(*at(pg, *obj["mass_center"]))
    pg.click("nav button[data-tab=views]")
    pg.wait_for_selector("#views figure img")
    pg.wait_for_function("() => [...document.querySelectorAll('#views img')].every(i => i.complete && "
                         "i.naturalWidth > 0)")
    assert pg.locator("#views figure").count() >= 1
    pg.screenshot(path=str(shots / "2_views.png"))

    # objects: accept a map proposal, draw a footprint, save the objects file
    pg.click("nav button[data-tab=objects]")
    pg.wait_for_selector("#object-list li")
    n = pg.locator("#object-list li").count()
    chair = next(o["cls"] for o in data["objects"] if o["cls"] == "chair") if any(
        o["cls"] == "chair" for o in data["objects"]) else obj["cls"]
    pg.fill("#propose-text", chair)
    pg.click("#propose")
    pg.wait_for_selector("#proposals li")
    pg.screenshot(path=str(shots / "3_proposals.png"))
    pg.click("#proposals li >> nth=0 >> text=accept")
    pg.click("#draw")
    corners = [(6.0, 3.0), (6.6, 3.0), (6.6, 3.5), (6.0, 3.5)]
    for xy in corners:
        pg.mouse.click(*at(pg, *xy))
    pg.click("#draw-done")
    assert pg.locator("#object-list li").count() == n + 2
    pg.keyboard.down("Shift")  # shift + drag moves the drawn footprint 0.5 m east
    pg.mouse.move(*at(pg, 6.3, 3.25))
    pg.mouse.down()
    pg.mouse.move(*at(pg, 6.8, 3.25), steps=5)
    pg.mouse.up()
    pg.keyboard.up("Shift")
    corners = [(x + 0.5, y) for x, y in corners]
    pg.fill("#object-form input[name=color_name]", "red")
    pg.fill("#objects-path", "objects/drawn.yaml")
    pg.click("#objects-save")
    pg.wait_for_selector("#objects-result:not(:empty)")
    pg.screenshot(path=str(shots / "4_objects.png"))
    saved = objects_from_file(root / "objects" / "drawn.yaml", SCENE)
    drawn = saved.objects[-1]
    assert len(saved.objects) == n + 2 and drawn.color_name == "red" and drawn.key == f"{chair}_" + drawn.key.split(
        "_")[-1]
    assert [tuple(round(v, 1) for v in p) for p in drawn.footprint] == corners

    # a new goal with descriptive and procedural feedback
    doc = pg.evaluate("() => S.doc")
    in_goals = {k for g in doc["goals"] for k in g["objects"]}
    identities = [o["identity"].lower() for o in doc["objects"].values()]
    target = next(o for o in data["objects"] if o["key"] not in in_goals and o["key"] in doc["objects"]
                  and identities.count(doc["objects"][o["key"]]["identity"].lower()) == 1
                  and pg.evaluate(f"() => objectShapes().find(o => inside({o['mass_center']}, o.footprint)).key")
                  == o["key"])
    pg.click("nav button[data-tab=goals]")
    pg.mouse.click(*at(pg, *target["mass_center"]))
    pg.click("#goal-new")
    pg.fill("#goal-form input[name=name]", "Alice's reading spot")
    pg.fill("#goal-form textarea[name=descriptive]", f"It is a {target['cls']} by the wall.")
    start = data["routes"][0]["start"]
    pg.click("#route-pick")
    pg.mouse.click(*at(pg, start[0], start[1]))
    pg.wait_for_selector("#route-use:not([hidden])")
    pg.click("#route-use")
    procedural = pg.input_value("#goal-form textarea[name=procedural]")
    assert procedural and "go forward" in procedural
    pg.wait_for_function("() => !document.getElementById('goals-save').disabled")
    assert pg.inner_text("#goal-error") == ""
    pg.screenshot(path=str(shots / "5_goal_edit.png"))
    routes_before = Manifest.read(root / "manifests" / SCENE / "routes.json")
    pg.click("#goals-save")
    pg.wait_for_function("() => document.getElementById('save-result').textContent.startsWith('saved')",
                         timeout=180_000)
    pg.wait_for_selector(f"body[data-ready={SCENE}]")
    assert pg.evaluate("() => S.doc.goals.some(g => g.name === \"Alice's reading spot\")")
    pg.screenshot(path=str(shots / "6_saved.png"))
    exported = goals_export(root)
    mine = next(g for g in exported["goals"] if g["name"] == "Alice's reading spot")
    assert mine["objects"] == [target["key"]] and mine["feedback"]["procedural"] == procedural
    assert mine["feedback"]["descriptive"] == f"It is a {target['cls']} by the wall."
    assert Manifest.read(root / "manifests" / SCENE / "routes.json").inputs != routes_before.inputs

    # an invalid edit: shown inline, nothing saved
    params_text = (root / "params.yaml").read_bytes()
    edits = sorted((root / "goals_edits").iterdir())
    pg.click("#goal-list li >> nth=1")
    pg.fill("#goal-form input[name=name]", '<img id="injected" src="x">')  # user text is shown as text
    pg.wait_for_function("() => document.querySelector('#goal-list li.selected').textContent.startsWith('<img')")
    assert pg.locator("#injected").count() == 0
    first = exported["goals"][0]["name"]
    pg.fill("#goal-form input[name=name]", first.upper())
    pg.wait_for_function("() => document.getElementById('goal-error').textContent.includes('not unique')")
    assert pg.is_disabled("#goals-save")
    pg.screenshot(path=str(shots / "7_invalid.png"))
    assert (root / "params.yaml").read_bytes() == params_text and sorted((root / "goals_edits").iterdir()) == edits

    # history
    pg.click("nav button[data-tab=history]")
    pg.wait_for_selector("#history li button")
    assert "(current)" in pg.inner_text("#history li >> nth=0")

    # play as the user: answer each question with the simulated user's reply until the episode ends
    pg.click("nav button[data-tab=play]")
    pg.wait_for_selector("#play-agent option", state="attached")
    pg.select_option("#play-agent", "vlmap")
    ambiguous = next((g["id"] for g in exported["goals"] if g["type"] == "ambiguous"), exported["goals"][0]["id"])
    pg.select_option("#play-goal", ambiguous)
    pg.click("#play-start")
    for _ in range(12):
        pg.wait_for_function("() => S.play && !['running', 'sent'].includes(S.play.status)", timeout=60_000)
        if pg.evaluate("() => S.play.status") != "waiting":
            break
        pg.screenshot(path=str(shots / "8_play_question.png"))
        pg.click("#play-suggest")
        pg.click("#play-send")
    pg.wait_for_function("() => S.play.status === 'done'", timeout=60_000)
    pg.screenshot(path=str(shots / "9_play_done.png"))
    assert "episode over" in pg.inner_text("#play-status")
    [record] = [json.loads(line) for line in (root / "data" / "eval" / "human" / f"{SCENE}.episodes.jsonl")
                .read_text().splitlines()]
    assert record["feedback"] == "human" and record["method"] == "vlmap" and record["goal"] == ambiguous
    assert record["talk_turns"] == sum(d["speaker"] == "agent" for d in record["log"]["dialogue"]) >= 1
    print(f"screenshots: {shots}")


@pytest.mark.slow
def test_an_objects_edit_is_dropped_only_when_the_user_says_so_and_cleanly(page, served):
    url, root = served
    pg = page
    errors, asked = [], []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.goto(url)
    pg.wait_for_selector(f"body[data-ready={SCENE}]")
    pg.click("nav button[data-tab=objects]")
    pg.wait_for_selector("#object-list li")
    on_disk = pg.evaluate("() => structuredClone(S.objects)")
    first = on_disk["objects"][0]["key"]

    # leaving the tab with an edit not saved asks first; "cancel" stays on the tab with the edit
    pg.click("#object-list li >> nth=0")
    pg.fill("#object-form input[name=color_name]", "purple")
    pg.once("dialog", lambda d: (asked.append(d.message), d.dismiss()))
    pg.click("nav button[data-tab=goals]")
    assert asked == ["The objects file has edits that are not saved. Drop them?"]
    assert pg.is_visible("#tab-objects") and pg.evaluate("() => S.objects.objects[0].color_name") == "purple"

    # "OK" drops it at once, also the check an edit runs 200 ms after the last keystroke (it used to fire after the
    # tab was left and read the dropped copy: a page error)
    pg.fill("#object-form input[name=color_name]", "green")
    pg.once("dialog", lambda d: (asked.append(d.message), d.accept()))
    pg.click("nav button[data-tab=goals]")
    pg.wait_for_timeout(600)
    assert len(asked) == 2 and pg.is_visible("#tab-goals") and pg.evaluate("() => S.objects") is None
    assert errors == [] and pg.locator("#object-list li").count() == 0 and pg.inner_text("#objects-error") == ""

    # back on the tab the file is read again, as it is on disk; with nothing edited, leaving asks nothing
    pg.click("nav button[data-tab=objects]")
    pg.wait_for_selector("#object-list li")
    assert pg.evaluate("() => S.objects") == on_disk
    pg.click("nav button[data-tab=goals]")
    pg.click("nav button[data-tab=objects]")
    pg.wait_for_selector("#object-list li")
    assert len(asked) == 2

    # a scene (re)load while editing shows that scene's file as it is on disk, not the last scene's edited copy
    pg.click("#object-list li >> nth=0")
    pg.fill("#object-form input[name=color_name]", "purple")
    pg.evaluate("() => loadScene(S.scene, true)")
    pg.wait_for_selector(f"body[data-ready={SCENE}]")
    pg.wait_for_timeout(600)
    assert errors == [] and pg.evaluate("() => S.objects") == on_disk
    assert pg.locator("#object-list li").count() == len(on_disk["objects"]) and pg.is_hidden("#object-form")
    assert pg.inner_text("#object-list li >> nth=0").startswith(first)

    # choosing a scene asks the same (cancel keeps the scene and the edit)
    pg.click("#object-list li >> nth=0")
    pg.fill("#object-form input[name=color_name]", "purple")
    pg.once("dialog", lambda d: (asked.append(d.message), d.dismiss()))
    pg.evaluate("() => document.getElementById('scene').dispatchEvent(new Event('change'))")
    assert len(asked) == 3 and pg.evaluate("() => [S.scene, S.objects.objects[0].color_name]") == [SCENE, "purple"]
    # closing the page: the handler cancels the unload, which is what makes the browser ask (headless Chromium
    # closes without showing that dialog, so the event is sent here as the browser sends it)
    leave = ("() => { const e = new Event('beforeunload', {cancelable: true}); window.dispatchEvent(e); "
             "return e.defaultPrevented; }")
    assert pg.evaluate(leave) is True
    pg.click("#objects-save")
    pg.wait_for_selector("#objects-result:not(:empty)")
    assert pg.evaluate(leave) is False and errors == []


@pytest.mark.slow
def test_a_two_storey_house_floor_by_floor(built_house, tmp_path):
    """The floor selector shows each floor's map, objects, goals and routes; a goal upstairs is shown upstairs and
    its route from the recording's start climbs the stairs (the stored procedural feedback, drawn on both floors);
    a route picked upstairs goes down; an object drawn upstairs is saved on floor 1."""
    from pipeline.goals.objects import objects_from_file
    from pipeline.goals.store import Goals

    root = copy_built(built_house[0], tmp_path / "ws")
    shots = tmp_path / "screenshots"
    shots.mkdir()
    stored = Goals(root / "data" / "artifacts" / "house" / "goals.zarr")
    with serving(root) as url, chromium_page() as pg:
        pg.goto(url + "#house")
        pg.wait_for_selector("body[data-ready=house]")
        assert pg.is_visible("#floor") and pg.locator("#floor option").count() == 2
        assert "2 floors, 1 stairs" in pg.inner_text("#status")
        data = pg.evaluate("() => S.data")
        per_floor = {k: sorted(o["key"] for o in data["objects"] if o["floor"] == k) for k in (0, 1)}
        shown = lambda: sorted(pg.evaluate("() => objectShapes().map(o => o.key)"))  # noqa: E731
        layer_ready = "k => S.layers['color@' + k] && S.layers['color@' + k].img && " \
                      "S.layers['color@' + k].img.naturalWidth > 0"
        pg.wait_for_function(f"() => ({layer_ready})(0)")
        assert shown() == per_floor[0] and per_floor[1]
        pg.screenshot(path=str(shots / "1_floor0.png"))
        map0 = pg.locator("#map").screenshot()

        pg.select_option("#floor", "1")
        pg.wait_for_function(f"() => ({layer_ready})(1)")
        assert pg.evaluate("() => S.layers['color@1'].url").endswith("&floor=1")
        assert shown() == per_floor[1] and pg.locator("#map").screenshot() != map0
        pg.screenshot(path=str(shots / "2_floor1.png"))

        # a goal upstairs, chosen while downstairs, is shown upstairs; its preview from the recording's start
        # climbs the stairs and says its stored procedural feedback
        pg.select_option("#floor", "0")
        upper = next(i for i, g in enumerate(stored.goals) if g.floor == 1 and g.feedback["procedural"])
        pg.click(f"#goal-list li >> nth={upper}")
        assert pg.evaluate("() => S.floor") == 1 and "floor 1" in pg.inner_text(f"#goal-list li >> nth={upper}")
        pg.click("#route-recorded")
        pg.wait_for_selector("#route-use:not([hidden])")
        route = pg.evaluate("() => S.route")
        assert route["text"] == stored.goals[upper].feedback["procedural"] and "go up the stairs" in route["text"]
        assert [leg["floor"] for leg in route["legs"]] == [0, 1] and pg.evaluate("() => S.floor") == 0
        assert "on floor 0" in pg.inner_text("#route-text")
        pg.screenshot(path=str(shots / "3_route_downstairs.png"))
        pg.select_option("#floor", "1")
        pg.wait_for_function(f"() => ({layer_ready})(1)")
        pg.screenshot(path=str(shots / "4_route_upstairs.png"))

        # a start picked upstairs, to a goal downstairs: down the stairs
        lower = next(i for i, g in enumerate(stored.goals) if g.floor == 0 and g.feedback["procedural"])
        pg.click(f"#goal-list li >> nth={lower}")
        assert pg.evaluate("() => S.floor") == 0
        pg.select_option("#floor", "1")
        start = next(r["start"] for r in data["routes"] if r["start_floor"] == 1)
        pg.click("#route-pick")
        pg.mouse.click(*at(pg, start[0], start[1]))
        pg.wait_for_function("() => document.getElementById('route-text').textContent.includes('stairs')")
        assert "go down the stairs" in pg.inner_text("#route-text")
        assert pg.evaluate("() => S.route.legs.map(l => l.floor)") == [1, 0]
        pg.screenshot(path=str(shots / "5_route_down.png"))

        # an object drawn upstairs is saved on floor 1, and is not drawn downstairs
        pg.click("nav button[data-tab=objects]")
        pg.wait_for_selector("#object-list li")
        assert pg.evaluate("() => S.floor") == 1
        pg.click("#draw")
        corners = [(4.0, 6.0), (4.6, 6.0), (4.6, 6.5), (4.0, 6.5)]
        for xy in corners:
            pg.mouse.click(*at(pg, *xy))
        pg.click("#draw-done")
        new = pg.evaluate("() => S.objects.objects[S.objects.objects.length - 1]")
        assert new["floor"] == 1 and pg.is_visible("#object-form select[name=floor]")
        assert pg.input_value("#object-form select[name=floor]") == "1"
        pg.fill("#objects-path", "objects/house.yaml")
        pg.wait_for_function("() => !document.getElementById('objects-save').disabled")
        pg.click("#objects-save")
        pg.wait_for_selector("#objects-result:not(:empty)")
        pg.screenshot(path=str(shots / "6_object_upstairs.png"))
        saved = {o.key: o.floor for o in objects_from_file(root / "objects" / "house.yaml", "house").objects}
        assert saved[new["key"]] == 1 and {k: saved[k] for k in per_floor[1]} == {k: 1 for k in per_floor[1]}
        pg.select_option("#floor", "0")
        assert new["key"] not in shown()
    print(f"screenshots: {shots}")


@pytest.mark.slow
def test_the_map_asks_for_the_window_it_shows(page, served, tmp_path):
    """The layer is the floor at a zoom that fits the screen, then, zoomed in, the part shown at one pixel per cell:
    the server paints only that window (zipon/annotate/layers.py), never the whole floor per request."""
    pg, _, shots = opened(page, served, tmp_path)
    ready = "() => { const l = S.layers['color@0']; return l && l.img && !l.pending && l.img.naturalWidth > 0; }"
    pg.wait_for_function(ready)
    g = pg.evaluate("() => S.data.grid")
    first = pg.evaluate("() => ({url: S.layers['color@0'].url, extent: S.layers['color@0'].extent, "
                        "stride: S.layers['color@0'].stride, w: S.layers['color@0'].img.naturalWidth, "
                        "h: S.layers['color@0'].img.naturalHeight})")
    assert "region=" in first["url"] and "px=" in first["url"]
    ex0, ex1, ey0, ey1 = first["extent"]
    gx0, gx1, gy0, gy1 = g["extent_xy"]
    ox0, ox1, oy0, oy1 = g["observed_xy"]
    assert ex0 <= ox0 and ex1 >= ox1 and ey0 <= oy0 and ey1 >= oy1  # the observed floor is in it
    assert (ex1 - ex0) * (ey1 - ey0) < (gx1 - gx0) * (gy1 - gy0)  # not the whole (mostly empty) grid
    assert first["stride"] == 1  # this small floor fits the screen at one pixel per cell
    pg.screenshot(path=str(shots / "1_fit.png"))
    box = pg.locator("#map").bounding_box()
    middle = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)

    def zoom(steps: int, dy: int) -> dict:
        """``steps`` turns of the mouse wheel on the map's middle, in one go (as a fast spin of the wheel)."""
        before = pg.evaluate("() => S.layers['color@0'].url")
        pg.evaluate(f"""() => {{ const r = canvas.getBoundingClientRect();
            for (let i = 0; i < {steps}; i++) canvas.dispatchEvent(new WheelEvent("wheel", {{deltaY: {dy},
                clientX: r.left + r.width / 2, clientY: r.top + r.height / 2, bubbles: true, cancelable: true}})); }}""")
        pg.wait_for_function("() => { const l = S.layers['color@0']; return l && l.img && !l.pending && "
                             f"l.url !== {before!r}; }}")
        return pg.evaluate("() => ({extent: S.layers['color@0'].extent, stride: S.layers['color@0'].stride, "
                           "w: S.layers['color@0'].img.naturalWidth, h: S.layers['color@0'].img.naturalHeight})")

    # zoomed far out: the whole grid at a zoom that fits, every k-th cell
    out = zoom(20, 120)
    assert out["stride"] > 1 and out["extent"] == pytest.approx([gx0, gx1, gy0, gy1], abs=out["stride"] * 0.05)
    assert max(out["w"], out["h"]) <= max(box["width"], box["height"]) * 2
    seen = pg.evaluate("""() => { const img = S.layers['color@0'].img, c = document.createElement("canvas");
        c.width = img.naturalWidth; c.height = img.naturalHeight; const x = c.getContext("2d"); x.drawImage(img, 0, 0);
        const d = x.getImageData(0, 0, c.width, c.height).data; let n = 0;
        for (let i = 3; i < d.length; i += 4) n += d[i] > 0; return n; }""")
    fx0, fx1, fy0, fy1 = g["observed_xy"]  # the floor's cells, every stride-th: about its area in pixels
    assert seen == pytest.approx((fx1 - fx0) * (fy1 - fy0) / (out["stride"] * 0.05) ** 2, rel=0.5)
    pg.screenshot(path=str(shots / "2_zoomed_out.png"))
    out_map = pg.locator("#map").screenshot()
    # zoomed far in on the middle: the part shown (and half a screen around it), one pixel per cell
    zoomed = zoom(34, -120)
    zx0, zx1, zy0, zy1 = zoomed["extent"]
    assert zoomed["stride"] == 1 and (zx1 - zx0) < 0.5 * (gx1 - gx0)
    assert zoomed["w"] == round((zx1 - zx0) / g["cell_size_m"])
    vis = pg.evaluate("() => [toWorld(0, canvas.clientHeight), toWorld(canvas.clientWidth, 0)]")
    assert zx0 <= max(vis[0][0], gx0) + 1e-3 and zx1 >= min(vis[1][0], gx1) - 1e-3  # covers what is shown
    assert zy0 <= max(vis[0][1], gy0) + 1e-3 and zy1 >= min(vis[1][1], gy1) - 1e-3
    pg.screenshot(path=str(shots / "3_zoomed_in.png"))
    assert pg.locator("#map").screenshot() != out_map
    # a small pan stays inside the loaded window: nothing new is asked
    url_before = pg.evaluate("() => S.layers['color@0'].url")
    pg.mouse.move(*middle)
    pg.mouse.down()
    pg.mouse.move(middle[0] + 40, middle[1] + 20, steps=4)
    pg.mouse.up()
    pg.wait_for_timeout(400)
    assert pg.evaluate("() => S.layers['color@0'].url") == url_before
    print(f"screenshots: {shots}")
