"""The simulated user's replies and the agents' parser of them."""

import re

import numpy as np
import pytest

from orion_eval.agents.base import ParsedFeedback, parse_feedback
from orion_eval.scene import SceneContext
from orion_eval.user import FEEDBACK_KIND_NAMES, SimulatedUser
from pipeline.errors import ConfigError
from pipeline.goals.feedback import FEEDBACK_KINDS
from pipeline.goals.feedback.base import appearance
from pipeline.goals.feedback.procedural import POINTING, parse_route
from pipeline.scene import Scene
from stages import STAGES


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
    text, kind = replies["mixed"]
    kinds = kind.split("+")
    assert "descriptive" in kinds and kinds == [k for k in FEEDBACK_KIND_NAMES if k in kinds]
    singles = [SimulatedUser(ctx, goal, k, np.random.default_rng(3)).respond(far)[1] for k in kinds]
    assert text == "No. " + " ".join(t.removeprefix("No. ") for t in singles)


def test_procedural_is_spoken_like_a_person(tiny_scene):
    """Whole metres, misjudged by a seeded factor; a route in another room (at most 3 parts), else a point."""
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


# ----------------------------------------------------------------------------- round trip per feedback kind
# generated by the goals stage -> said by the simulated user -> read by the agents' parser: what the agent reads,
# said again in the kind's words, is what the user said


def _say_again(kind: str, fb: ParsedFeedback, goal) -> str:
    """The sentence ``fb`` holds of ``kind``, in the user's words (the inverse of the kind's parse)."""
    metres = lambda m: f"{int(m)} meter" if int(m) == 1 else f"{int(m)} meters"
    if kind == "corrective":
        return f"This is {fb.corrected_as}, not {goal.name}."
    if kind == "descriptive":
        return f"It is {'an' if fb.description[0] in 'aeiou' else 'a'} {fb.description}."
    if kind == "procedural" and fb.route:
        words = {90.0: "turn left", -90.0: "turn right", 180.0: "turn around"}
        return "Follow this route: " + ", ".join(words[v] if k == "turn" else f"go forward {metres(v)}"
                                                  for k, v in fb.route) + "."
    bearing, distance = fb.destination
    return f"It is about {metres(distance)} {POINTING[int(round(bearing / 45.0)) % 8]}."


def _poses_facing(center, radii=(0.8, 1.2, 1.8)):
    """Poses around ``center`` looking at it (x, y, yaw)."""
    for r in radii:
        for a in np.linspace(0, 2 * np.pi, 16, endpoint=False):
            yield np.array([center[0] + r * np.cos(a), center[1] + r * np.sin(a), a + np.pi])


def _said(ctx, goal, kind):
    """``[(pose, what the user said of kind there)]`` over the poses where the kind has something to say."""
    user = SimulatedUser(ctx, goal, kind, np.random.default_rng(0))
    if kind == "corrective":
        poses = [p for k in sorted(goal.feedback["corrective"])
                 for p in _poses_facing(ctx.scene.goals.objects[k].mass_center)]
    else:
        poses = [ep.start for g in ctx.scene.goals.goals for ep in ctx.scene.routes.for_goal(g.id)]
    return user, [(pose, text) for pose in poses if (text := user.feedback(kind, pose))]


@pytest.mark.parametrize("kind", sorted(FEEDBACK_KINDS))
def test_each_kind_round_trips_generated_said_parsed(tiny_scene, kind):
    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    document = ctx.scene.goals.document
    checked = 0
    for goal in ctx.scene.goals.goals:
        user, said = _said(ctx, goal, kind)
        for pose, text in said:
            fb = parse_feedback(f"No. {text}")
            assert not fb.yes
            # the kind's attributes only: the other kinds read nothing in its sentence
            others = {a: v for k, cls in FEEDBACK_KINDS.items() if k != kind for a, v in vars(fb).items()
                      if a in cls.parsed}
            assert others == {a: e() for k, cls in FEEDBACK_KINDS.items() if k != kind for a, e in cls.parsed.items()}
            stored = goal.feedback[kind]
            if kind == "corrective":  # said: the stored line of the object looked at, naming that object
                looked = user.looked_at(pose, sorted(stored))
                assert text == stored[looked] and fb.corrected_as == document.objects[looked].identity
            elif kind == "descriptive":  # said as generated; read: what the goal looks like
                assert text == stored and fb.description == appearance(ctx.scene.goals.objects[goal.id])
            elif kind == "landmark":  # said as generated; read: one phrase per landmark, each naming its object
                assert text == stored
                rels = "|".join(("next to", "near", "on", "under"))
                said_again = [f"{re.match(rf'({rels}) ', p).group(1)} {fb.landmarks[i]}" for i, p in
                              enumerate(re.split(r",\s*|\s+and\s+", text.removeprefix("It is ").rstrip(".")))]
                assert len(fb.landmarks) == len(said_again) > 0
                assert text == "It is " + (said_again[0] if len(said_again) == 1 else
                                           ", ".join(said_again[:-1]) + " and " + said_again[-1]) + "."
                classes = [ctx.scene.goals.objects[r["object"]].cls for r in goal.landmarks]
                assert all(any(c in phrase for c in classes) for phrase in fb.landmarks)
            else:  # planned from the pose: the route's turns and legs, or the goal's direction
                route = user.route_from(pose)
                if fb.route:
                    assert [k for k, _ in fb.route] == ["turn" if p.kind != "go forward" else "forward"
                                                         for p in route.parts]
                else:
                    x, y, yaw = pose
                    dx, dy = np.asarray(goal.mass_center) - (x, y)
                    off = (np.degrees(np.arctan2(dy, dx) - yaw) - fb.destination[0] + 180.0) % 360.0 - 180.0
                    assert abs(off) <= 22.5 + 1e-6 and fb.destination[1] >= 1
            if kind == "descriptive":
                assert text.startswith(_say_again(kind, fb, goal))
            elif kind != "landmark":
                assert _say_again(kind, fb, goal) == text
            # one reply holding every kind reads the same for this kind
            mixed = parse_feedback("No. " + " ".join(
                t for k in FEEDBACK_KIND_NAMES if (t := text if k == kind else user.feedback(k, pose))))
            assert {a: getattr(mixed, a) for a in FEEDBACK_KINDS[kind].parsed} == \
                   {a: getattr(fb, a) for a in FEEDBACK_KINDS[kind].parsed}
            checked += 1
    assert checked, f"no goal of the scene has {kind} feedback to say"


def test_an_unknown_kind_is_an_error_naming_the_registered_kinds(tiny_scene):
    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    goal = ctx.scene.goals.goals[0]
    user = SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0))
    with pytest.raises(ConfigError, match=r"feedback kind 'gesture': unknown; the registered kinds are "
                                          r"\['corrective', 'descriptive', 'landmark', 'procedural'\]"):
        user.feedback("gesture", ctx.scene.routes.for_goal(goal.id)[0].start)
    with pytest.raises(ValueError, match="unknown feedback setting 'gesture'"):
        SimulatedUser(ctx, goal, "gesture", np.random.default_rng(0))
    with pytest.raises(TypeError, match=r"\['gesture'\] are filled by no feedback kind"):
        ParsedFeedback(gesture="wave")


def test_parse_the_stairs_and_the_floor_of_a_building():
    """The user's words across floors: the procedural kind says the stairs and what follows them, the landmark kind
    which floor; the agents read back the flights, the route after them and the floor offset."""
    fb = parse_feedback("No. Go up the stairs. At the top, follow this route: turn right, go forward 4 meters.")
    assert fb.stairs == ["up"] and fb.route == [("turn", -90.0), ("forward", 4.0)] and fb.destination is None
    fb = parse_feedback("No. Go down 2 flights of stairs. At the bottom, it is about 5 meters behind you on the right.")
    assert fb.stairs == ["down", "down"] and fb.destination == (-135.0, 5.0) and fb.route == []
    fb = parse_feedback("No. It is upstairs. It is next to the bed.")
    assert fb.floor_offset == 1 and fb.landmarks == ["the bed"] and fb.stairs == []
    assert parse_feedback("No. It is 2 floors down.").floor_offset == -2
    single = parse_feedback("No. It is next to the bed. Follow this route: turn left, go forward 3 meters.")
    assert single.stairs == [] and single.floor_offset == 0  # nothing of floors on a single floor


def test_from_another_floor_the_user_names_the_stairs_and_the_floor(tiny_house):
    """The user's procedural directions from another floor are planned over the stairs (as the goals stage plans
    them) and say them; the landmark kind says which floor; success is judged on the goal's floor only."""
    from orion_eval.world import Pose

    ws, params = tiny_house
    ctx = SceneContext(Scene(ws, params, "house", STAGES, check=True))
    said = []
    for goal in ctx.scene.goals.goals:
        for ep in ctx.scene.routes.for_goal(goal.id):
            if ep.start_floor == goal.floor:
                continue
            pose = Pose(ep.start, ep.start_floor)
            way = "up" if goal.floor > ep.start_floor else "down"
            text = SimulatedUser(ctx, goal, "procedural", np.random.default_rng(0)).respond(pose)[1]
            assert text.startswith(f"No. Go {way} the stairs."), text
            fb = parse_feedback(text)
            assert fb.stairs == [way] and (fb.route or fb.destination or text.endswith("stairs."))
            land = SimulatedUser(ctx, goal, "landmark", np.random.default_rng(0)).respond(pose)[1]
            assert land.startswith(f"No. It is {'upstairs' if way == 'up' else 'downstairs'}.")
            assert parse_feedback(land).floor_offset == goal.floor - ep.start_floor
            # the goal's own place, seen from the other floor, is no success (nor a distance)
            assert not SimulatedUser(ctx, goal, "none", np.random.default_rng(0)).judge(
                Pose(tuple(goal.mass_center) + (0.0,), ep.start_floor))["success"]
            said.append(text)
    assert said
