import pytest

from pipeline.config import GoalsParams
from pipeline.goals.build import build_goals
from pipeline.goals.feedback import FEEDBACK_KINDS, FeedbackKind
from pipeline.goals.objects import objects_from_gt
from pipeline.nav.actions import RoutePlanner
from tests.fixtures.goal_scenes import gt_navigable, house_grid, house_scene


@pytest.fixture(scope="module")
def house_goals():
    gt, grid = house_scene(), house_grid()
    walls = gt.occupancy(grid, 0.05, 2.5, objects=False)
    planner = RoutePlanner(gt_navigable(gt, grid), grid)
    return build_goals(objects_from_gt(gt), grid, walls, planner=planner, start_pose=(2.5, 1.8, 0.0),
                       settings=GoalsParams(max_goals=20))


@pytest.mark.parametrize("kind", sorted(FEEDBACK_KINDS))
class TestFeedbackKind:
    """Every feedback kind: registered under its name, JSON-able values for every goal."""

    def test_registered(self, kind):
        assert issubclass(FEEDBACK_KINDS[kind], FeedbackKind) and FEEDBACK_KINDS[kind].name == kind

    def test_value_on_every_goal(self, kind, house_goals):
        """Every goal gets a JSON-able value of this kind, and most goals a non-empty one."""
        import json

        values = [getattr(g.feedback, kind) for g in house_goals.document.goals]
        for value in values:
            json.dumps(value)
            assert value is None or isinstance(value, (str, dict))
        assert sum(bool(v) for v in values) >= 0.6 * len(values), values


def test_each_kind_says_what_the_paper_s_feedback_says(house_goals):
    """Corrective: 'This is X, not <goal>' for every other object; descriptive: the goal's class, colour and
    material; landmark: another object of the scene near the goal; procedural: turns and rounded distances."""
    import re

    doc = house_goals.document
    objects = doc.objects
    records = {o.key: o for o in objects_from_gt(house_scene()).objects}
    for g in doc.goals:
        fb, mine = g.feedback, set(g.objects)
        assert set(fb.corrective) == set(objects) - mine
        assert all(text.startswith("This is ") and text.endswith(f", not {g.name}.") for text in fb.corrective.values())
        first = records[g.objects[0]]
        assert f" {first.cls} " in fb.descriptive and f"{first.color_name} " in fb.descriptive
        assert f"made of {first.material}" in fb.descriptive
        if fb.landmark:
            others = [r for k, r in records.items() if k not in mine]
            assert fb.landmark.startswith("It is ") and any(f" {r.cls}" in fb.landmark for r in others)
        steps = fb.procedural.split(", ")
        assert all(re.fullmatch(r"turn (left|right|around)|go forward \d+(\.5)? meters", s) for s in steps), steps


GESTURE = '''"""A made-up kind, as a contributor adds one: its one module."""

import re

from pydantic import Field

from pipeline.goals.feedback.base import FeedbackKind, register


@register
class Gesture(FeedbackKind):
    name = "gesture"
    field = (str, Field("", description="where the user points"))
    parsed = {"pointed_at": lambda: None}

    def generate(self, goal, ctx):
        return f"Look over there, at {goal.name}!"

    def parse(self, reply):
        m = re.search(r"Look over there, at (.+?)!", reply)
        return {"pointed_at": m.group(1)} if m else {}
'''

ADDED = """
import json
from pipeline.config import GoalsParams
from pipeline.goals.build import build_goals
from pipeline.goals.feedback import feedback_kind
from pipeline.goals.objects import objects_from_gt
from pipeline.goals.schema import Feedback
from pipeline.nav.actions import RoutePlanner
from orion_eval.agents import parse_feedback
from orion_eval.user import FEEDBACK_SETTINGS
from tests.fixtures.goal_scenes import gt_navigable, house_grid, house_scene

gt, grid = house_scene(), house_grid()
res = build_goals(objects_from_gt(gt), grid, gt.occupancy(grid, 0.05, 2.5, objects=False),
                  planner=RoutePlanner(gt_navigable(gt, grid), grid), start_pose=(2.5, 1.8, 0.0),
                  settings=GoalsParams(max_goals=3))
goal = res.document.goals[0]
said = feedback_kind("gesture").say(goal.feedback.gesture, None, None)
read = parse_feedback("No. " + said + " " + goal.feedback.descriptive)
print(json.dumps({"fields": list(Feedback.model_fields), "settings": FEEDBACK_SETTINGS, "name": goal.name,
                  "stored": goal.feedback.gesture, "pointed_at": read.pointed_at, "description": read.description}))
"""


def test_a_kind_added_as_its_one_module_is_generated_stored_said_and_read(tmp_path):
    """Adding a kind touches its module and nothing else: in a copy of the library with one new file, the goals
    stage generates and stores it (the goals document has its field), the evaluator offers it as a setting, the user
    says it and the agents' parser reads it back (beside the other kinds of the same reply)."""
    import json
    import shutil
    import subprocess
    import sys

    from pipeline.engine.codedeps import ROOT

    for name in ("pipeline", "orion_eval"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "pipeline" / "goals" / "feedback" / "gesture.py").write_text(GESTURE)
    run = subprocess.run([sys.executable, "-c", ADDED], capture_output=True, text=True, cwd=tmp_path,
                         env={"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin"}, timeout=300)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["fields"] == ["corrective", "descriptive", "gesture", "landmark", "procedural"]
    assert out["settings"] == ["none", "yesno", *out["fields"], "mixed"]
    assert out["stored"] == f"Look over there, at {out['name']}!" and out["pointed_at"] == out["name"]
    assert out["description"]  # the other kinds still read their part of the reply


def test_a_kind_reading_another_kind_s_attribute_is_refused():
    from pipeline.goals.feedback.base import register

    class Pointing(FeedbackKind):
        name = "pointing"
        field = (str, None)
        parsed = {"route": list}

        def generate(self, goal, ctx):
            return ""

        def parse(self, reply):
            return {}

    with pytest.raises(TypeError, match=r"feedback kind 'pointing' \(.*Pointing\): parsed attribute\(s\) \['route'\] "
                                        r"already filled by \['procedural'\]"):
        register(Pointing)
    assert "pointing" not in FEEDBACK_KINDS


def _goal(res, gid):
    return next(g for g in res.document.goals if g.id == gid)


def test_types_and_same_goal(house_goals):
    chairs = _goal(house_goals, "chair_0")
    assert chairs.objects == ["chair_0", "chair_1"] and chairs.type == "ambiguous"
    assert _goal(house_goals, "couch_0").type == "big" and _goal(house_goals, "lamp_0").type == "small"
    assert "2 of them" in chairs.feedback.descriptive


def test_corrective_names_the_other_objects_identity(house_goals):
    doc = house_goals.document
    g = _goal(house_goals, "chair_2")
    assert set(g.feedback.corrective) >= {"chair_0", "chair_1", "chair_3"}
    assert g.feedback.corrective["chair_3"] == f"This is {doc.objects['chair_3'].identity}, not {g.name}."


def test_descriptive_from_attributes(house_goals):
    d = _goal(house_goals, "chair_2").feedback.descriptive
    assert d.startswith("It is a red chair made of wood.") and "0.9 meters tall" in d
    lamp = _goal(house_goals, "lamp_0").feedback.descriptive
    assert f"sits on {house_goals.document.objects['bed_1'].identity}" in lamp


def test_landmarks_relation_radius_and_line_of_sight(house_goals):
    lm = house_goals.landmarks
    assert lm["lamp_0"][0] == {"object": "bed_1", "relation": "on", "distance_m": 0.0}
    assert {"object": "table_0", "relation": "next to", "distance_m": 0.1} in lm["chair_0"]  # chair_1 is 0.1 m away
    # chair_2 (bedroom 1) is 0.3 m from the x = 5 wall; the living room beyond is never a landmark
    assert all(house_goals.document.objects[m["object"]].room == "bedroom_1" for m in lm["chair_2"])
    assert all(m["distance_m"] <= 1.0 for ms in lm.values() for m in ms)
    assert _goal(house_goals, "lamp_0").feedback.landmark.startswith("It is on ")


def test_landmarks_easy_to_find_come_first():
    """The paper's landmarks are "easily identifiable in the room": an object named by its class alone (the scene's
    one fridge) comes before a nearer one of a repeated class (one of two beds), which the user points out by what
    it looks like when that tells it apart, else by its identity; a pair is named once."""
    from tests.fixtures.goal_scenes import _obj

    gt, grid = house_scene(), house_grid()
    # a fridge 0.71 m from Carol's chair (chair_2, bedroom 1), whose bed is 0.54 m from it
    gt.objects.append(_obj(12, "fridge", "bedroom_1", 5.2, 4.4, 5.5, 4.9, 1.8, "white", (240, 240, 240), "metal",
                           "big"))
    res = build_goals(objects_from_gt(gt), grid, gt.occupancy(grid, 0.05, 2.5, objects=False),
                      planner=RoutePlanner(gt_navigable(gt, grid), grid), start_pose=(2.5, 1.8, 0.0),
                      settings=GoalsParams(max_goals=20))
    assert [m["object"] for m in res.landmarks["chair_2"]] == ["fridge_0", "bed_0"]
    assert res.landmarks["chair_2"][0]["distance_m"] > res.landmarks["chair_2"][1]["distance_m"]
    bed = next(o for o in objects_from_gt(gt).objects if o.key == "bed_0")
    beds = [o for o in gt.objects if o.cls == "bed"]
    assert len(beds) == 2 and len({(o.color_name, o.material) for o in beds}) == 2
    assert _goal(res, "chair_2").feedback.landmark == \
        f"It is near the fridge and near the {bed.color_name} bed made of {bed.material}."
    # the table's two chairs are one pair, one identity: named once
    assert _goal(res, "table_0").feedback.landmark == "It is next to the black chair made of metal."
    # two beds that look alike: only the bed's identity tells which
    gt.objects[:] = [o.model_copy(update={"color_name": "white", "material": "fabric"}) if o.cls == "bed" else o
                     for o in gt.objects]
    res = build_goals(objects_from_gt(gt), grid, gt.occupancy(grid, 0.05, 2.5, objects=False),
                      planner=RoutePlanner(gt_navigable(gt, grid), grid), start_pose=(2.5, 1.8, 0.0),
                      settings=GoalsParams(max_goals=20))
    assert _goal(res, "chair_2").feedback.landmark == \
        f"It is near the fridge and near {res.document.objects['bed_0'].identity}."


def test_procedural_from_the_start_pose(house_goals):
    # start (2.5, 1.8) facing east; Alice/Bob bedroom 2 through the door at y 1..2
    p = _goal(house_goals, "bed_1").feedback.procedural
    assert p is not None and p.startswith("go forward")
