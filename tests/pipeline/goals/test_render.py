"""Goals and routes pictures of a building, one per floor (pipeline/goals/render.py), on the simulated two-storey
house: each floor shows its own goals, the legs of the routes walked on it (a cross-floor route on every floor it
crosses), the stairs' ends and metre axes; a floor the scene lacks is refused naming its floors. (A single-floor
scene's pictures: tests/stages/test_goals_routes.py.)"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.errors import ConfigError
from pipeline.goals.render import STAIR_COLOUR, render_goals
from pipeline.pictures import AXIS_LEFT
from pipeline.goals.store import Goals
from pipeline.pictures import label_colors
from pipeline.routes.store import Routes


@pytest.fixture(scope="module")
def pictures(built_house, tmp_path_factory):
    ws, _ = built_house
    out = tmp_path_factory.mktemp("goal_pictures")
    art = {a: ws.artifact(a, "house") for a in ("recon", "goals", "routes")}
    images = {}
    for what in ("goals", "routes"):
        for k in (0, 1):
            png = render_goals(art["recon"], art["goals"], art["routes"], what, out / f"{what}_floor{k}.png", floor=k)
            images[what, k] = cv2.imread(str(png))[..., ::-1]  # RGB
    return art, images


def _has(img: np.ndarray, colour) -> int:
    return int(np.all(img == np.asarray(colour, np.uint8), axis=-1).sum())


def test_each_floor_shows_its_own_goals(pictures):
    art, images = pictures
    goals = Goals(art["goals"])
    colours = label_colors(np.arange(1, len(goals.goals) + 1)).reshape(-1, 3)
    assert {g.floor for g in goals.goals} == {0, 1}
    for g, c in zip(goals.goals, colours):
        on, off = images["goals", g.floor], images["goals", 1 - g.floor]
        assert _has(on, c) >= 20, g.id  # its footprint, its number's disc and its legend swatch
        assert _has(off, c) == 0, g.id  # not on the other floor, not in its legend


def test_a_cross_floor_route_is_drawn_on_every_floor_it_crosses_with_the_stairs_marked(pictures):
    art, images = pictures
    goals, routes = Goals(art["goals"]), Routes(art["routes"])
    colours = {g.id: c for g, c in zip(goals.goals, label_colors(np.arange(1, len(goals.goals) + 1)).reshape(-1, 3))}
    cross = [e for e in routes.episodes if len(e.floors) > 1]
    assert cross
    for e in cross:
        start_floor = e.start_floor
        assert goals.goal(e.goal_id).floor != start_floor
        # the goal's colour on the other floor: only its route's leg there (the goals picture has none of it)
        assert _has(images["routes", start_floor], colours[e.goal_id]) > _has(images["goals", start_floor],
                                                                                colours[e.goal_id]) == 0
    for k in (0, 1):
        assert _has(images["routes", k], STAIR_COLOUR) >= 50 and _has(images["goals", k], STAIR_COLOUR) >= 50


def test_the_pictures_have_metre_axes(pictures):
    _, images = pictures
    for img in images.values():
        margin = img[30:-120, :AXIS_LEFT - 7]  # left of the axis line, under the title band, above the legend
        assert (margin < 100).all(axis=-1).any()  # tick labels
        assert (img[30:-120, AXIS_LEFT - 1] < 100).all(axis=-1).mean() > 0.5  # the axis line


def test_a_floor_the_scene_lacks_is_refused(pictures, tmp_path):
    art, _ = pictures
    with pytest.raises(ConfigError, match=r"--floor 2: house has 2 floors \(0\.\.1\)"):
        render_goals(art["recon"], art["goals"], None, "goals", tmp_path / "x.png", floor=2)
    assert not (tmp_path / "x.png").exists()


def _walked(route) -> tuple[list, list]:
    """A cross-floor route's path as an evaluated episode logs it: poses ``[x, y, yaw]`` and the floor of each."""
    poses, floors = [], []
    for f, xy in route.legs():
        poses += [[float(x), float(y), 0.0] for x, y in xy]
        floors += [int(f)] * len(xy)
    return poses, floors


def test_a_cross_floor_episode_is_drawn_floor_by_floor(pictures, tmp_path):
    from pipeline.goals.render import render_episodes
    from pipeline.recon import Recon

    art, _ = pictures
    routes, goals = Routes(art["routes"]), Goals(art["goals"])
    route = next(e for e in routes.episodes if len(e.floors) > 1)
    poses, floors = _walked(route)
    colour = "#e6289b"
    one, both = render_episodes(art["recon"], art["goals"], [(route.goal_id, poses, colour),
                                                               (route.goal_id, poses, colour, floors)],
                                [tmp_path / "flat.png", tmp_path / "floors.png"])
    img = cv2.imread(str(both))[..., ::-1]
    panels = [Recon(art["recon"]).floor(f) for f in dict.fromkeys(floors)]
    # one panel per floor walked, side by side: the picture is wider than one floor's, the path on each
    assert len(panels) == 2 and img.shape[1] > cv2.imread(str(one)).shape[1] * 1.5
    path_cols = np.flatnonzero(np.all(img == (0xe6, 0x28, 0x9b), axis=-1).any(axis=0))
    half = img.shape[1] // 2
    assert (path_cols < half).sum() >= 20 and (path_cols >= half).sum() >= 20
    # the goal only on its own floor's panel (the second: the walk ends there), the stairs on both
    gold = np.flatnonzero(np.all(img == (255, 215, 0), axis=-1).any(axis=0))
    body = gold[gold < img.shape[1] - 1]
    assert goals.goal(route.goal_id).floor == floors[-1] != floors[0]
    assert (body >= half).sum() > 10 and (body[body < half] > 200).sum() == 0  # left panel: legend swatch only
    stair = np.flatnonzero(np.all(img == STAIR_COLOUR, axis=-1).any(axis=0))
    assert (stair < half).any() and (stair >= half).any()


def test_an_episode_with_a_floor_the_scene_lacks_is_refused(pictures, tmp_path):
    from pipeline.errors import InputDataError
    from pipeline.goals.render import render_episodes

    art, _ = pictures
    route = next(e for e in Routes(art["routes"]).episodes if len(e.floors) > 1)
    poses, floors = _walked(route)
    with pytest.raises(InputDataError, match=r"log\.floors.*one floor id of 0\.\.1 per pose"):
        render_episodes(art["recon"], art["goals"], [(route.goal_id, poses, "#000000", [3] * len(poses))],
                        [tmp_path / "x.png"])
    with pytest.raises(InputDataError, match=rf"{len(poses) - 1} floors .* for {len(poses)} poses"):
        render_episodes(art["recon"], art["goals"], [(route.goal_id, poses, "#000000", floors[:-1])],
                        [tmp_path / "x.png"])
    assert not (tmp_path / "x.png").exists()
