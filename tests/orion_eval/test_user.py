"""The simulated user's replies and the agents' parser of them."""

import numpy as np

from orion_eval.agents.base import parse_feedback, parse_route
from orion_eval.artifacts import Artifacts
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


def test_replies_per_setting_are_deterministic(tiny_scene):
    ws, params = tiny_scene
    ctx = SceneContext(Artifacts(ws, params, "tiny"))
    goal = ctx.arts.goals.goals[0]
    far = ctx.arts.routes.for_goal(goal.id)[0].start if ctx.arts.routes.for_goal(goal.id) else None
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
