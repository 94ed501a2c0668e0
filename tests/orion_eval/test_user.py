"""The simulated user's replies and the agents' parser of them."""

import numpy as np

from orion_eval.agents.base import parse_feedback, parse_route
from pipeline.scene import Scene
from stages import STAGES
from orion_eval.scene import SceneContext
from orion_eval.user import SimulatedUser


def test_parse_feedback_templates():
    assert parse_feedback("Yes, this is Alice's chair.").yes
    fb = parse_feedback("No. This is Bob's computer, not Alice's computer.")
    assert fb.corrected_as == "Bob's computer" and not fb.yes
    fb = parse_feedback("No. It is a red chair made of wood. It stands on the floor and is about 0.9 meters tall.")
    assert fb.description == "red chair made of wood" and fb.landmarks == []
    fb = parse_feedback("No. It is on the desk, next to Kate's chair and near Kate's shelf.")
    assert fb.landmarks == ["the desk", "Kate's chair", "Kate's shelf"] and fb.description is None
    fb = parse_feedback("No. Follow this route: turn left, go forward 2.5 meters, turn around.")
    assert fb.route == [("turn", 90.0), ("forward", 2.5), ("turn", 180.0)]
    assert parse_route("turn right, go forward 1 meter") == [("turn", -90.0), ("forward", 1.0)]
    assert parse_feedback("No. It is about 4 meters ahead on your left.").destination == (45.0, 4.0)
    assert parse_feedback("No. It is about 1 meter behind you.").destination == (180.0, 1.0)
    both = parse_feedback("No. This is Bob's chair, not Alice's chair. It is a red chair made of wood. It stands on "
                          "the floor and is about 0.9 meters tall. It is next to the bed. Follow this route: turn "
                          "left, go forward 3 meters.")
    assert (both.corrected_as, both.description, both.landmarks, both.route, both.destination) == (
        "Bob's chair", "red chair made of wood", ["the bed"], [("turn", 90.0), ("forward", 3.0)], None)


def test_replies_per_setting_are_deterministic(tiny_scene):
    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    goal = ctx.scene.goals.goals[0]
    far = ctx.scene.routes.for_goal(goal.id)[0].start if ctx.scene.routes.for_goal(goal.id) else None
    assert far is not None
    replies = {}
    for setting in ("none", "yesno", "descriptive", "landmark", "mixed"):
        u = SimulatedUser(ctx, goal, setting, np.random.default_rng(3))
        ok, text, kind = u.respond(far)
        assert not ok
        replies[setting] = (text, kind)
    assert replies["none"] == ("", "none") and replies["yesno"] == ("No.", "no")
    assert replies["descriptive"][0] == "No. " + goal.feedback["descriptive"]
    assert replies["landmark"][0] in ("No.", "No. " + goal.feedback["landmark"])
    again = SimulatedUser(ctx, goal, "mixed", np.random.default_rng(3)).respond(far)
    assert again[1:] == replies["mixed"]
    # mixed: every kind available at that pose in one reply, in the kinds' order
    from orion_eval.user import FEEDBACK_KIND_NAMES

    text, kind = replies["mixed"]
    kinds = kind.split("+")
    assert "descriptive" in kinds and kinds == [k for k in FEEDBACK_KIND_NAMES if k in kinds]
    singles = [SimulatedUser(ctx, goal, k, np.random.default_rng(3)).respond(far)[1] for k in kinds]
    assert text == "No. " + " ".join(t.removeprefix("No. ") for t in singles)


def test_procedural_is_spoken_like_a_person(tiny_scene):
    """Whole metres, misjudged by a seeded factor; a route in another room (at most 3 parts), else a point."""
    import re

    from orion_eval.user import POINTING

    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    said = []
    for goal in ctx.scene.goals.goals:
        for ep in ctx.scene.routes.for_goal(goal.id):
            text = SimulatedUser(ctx, goal, "procedural", np.random.default_rng(0)).procedural(ep.start)
            if text is None:
                continue
            said.append(text)
            route = re.fullmatch(r"Follow this route: (.+)\.", text)
            if route:
                parts = route.group(1).split(", ")
                assert 0 < len(parts) <= 3
                for p in parts:
                    assert p in ("turn left", "turn right", "turn around") or re.fullmatch(r"go forward \d+ meters?", p)
            else:
                m = re.fullmatch(r"It is about (\d+) meters? (.+)\.", text)
                assert m and m.group(2) in POINTING and int(m.group(1)) >= 1
                fb = parse_feedback("No. " + text)
                assert fb.destination is not None and fb.destination[1] == int(m.group(1))
    assert said
    goal = ctx.scene.goals.goals[0]
    u = SimulatedUser(ctx, goal, "procedural", np.random.default_rng(0))
    noisy = [u.say_metres(5.0, (i, 0)) for i in range(200)]
    assert {"4 meters", "5 meters", "6 meters"} <= set(noisy) and all(re.fullmatch(r"\d+ meters?", t) for t in noisy)
    again = SimulatedUser(ctx, goal, "mixed", np.random.default_rng(0))
    # keyed by what is judged, not by call order nor the setting: the same place and part, the same words
    assert [again.say_metres(5.0, (i, 0)) for i in reversed(range(200))] == noisy[::-1]
    other = SimulatedUser(ctx, goal, "procedural", np.random.default_rng(1))
    assert [other.say_metres(5.0, (i, 0)) for i in range(200)] != noisy


def test_settings_are_paired_on_the_spoken_route(tiny_scene):
    """The same (seed, goal) asked at the same place says the same route or point in 'procedural' and 'mixed',
    however often the user spoke before: settings differ only in which kinds are said."""
    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    compared = 0
    for goal in ctx.scene.goals.goals:
        starts = [ep.start for ep in ctx.scene.routes.for_goal(goal.id)]
        if not starts:
            continue
        proc = SimulatedUser(ctx, goal, "procedural", np.random.default_rng([0, 1]))
        mixed = SimulatedUser(ctx, goal, "mixed", np.random.default_rng([0, 1]))
        for pose in [*starts, *starts[::-1]]:  # asked again in another order: the same words at the same place
            said = proc.procedural(pose)
            if said is None:
                continue
            ok, reply, kind = mixed.respond(pose)
            assert not ok and kind.endswith("procedural") and reply.endswith(" " + said)
            compared += 1
    assert compared
