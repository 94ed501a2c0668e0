"""The one think-act-ask controller: baselines as module sets, and each kind of feedback acted on by the same
rules, through the modules a method has."""

import math
from dataclasses import astuple

import numpy as np
import pytest

from orion_eval.agents import AGENTS, build_agent
from orion_eval.agents.base import ParsedFeedback
from orion_eval.agents.controller import ModularAgent, ModuleSet, SearchState
from pipeline.nav.actions import LEFT
from pipeline.scene import Scene
from stages import STAGES
from orion_eval.episode import EpisodeRun, Task
from orion_eval.modules import FoundObject
from orion_eval.scene import SceneContext
from orion_eval.user import SimulatedUser


@pytest.fixture(scope="module")
def ctx(tiny_scene):
    ws, params = tiny_scene
    return SceneContext(Scene(ws, params, "tiny", STAGES, check=True))


def episode(ctx, method="orion", goal_index=0):
    goal = [g for g in ctx.scene.goals.goals if ctx.scene.routes.for_goal(g.id)][goal_index]
    ep = ctx.scene.routes.for_goal(goal.id)[0]
    task = Task("tiny", method, "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m)
    run = EpisodeRun(ctx, task, SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0)), 2000, 5)
    return goal, run, build_agent(method, ctx.params)


def test_baselines_are_module_subsets_of_one_controller():
    mods = {name: cls.modules for name, cls in AGENTS.items() if issubclass(cls, ModularAgent)}
    ablations = {"orion_wo_mem", "orion_wo_exp", "orion_wo_det", "orion_wo_map"}
    assert set(mods) == {"cow", "vlmap", "cf", "orion"} | ablations
    assert all(AGENTS[n].run is ModularAgent.run for n in mods)  # one policy, no per-method override
    assert mods["cow"] == ModuleSet(detector="saliency", explore=True)
    assert mods["vlmap"] == ModuleSet(map="vlmap") and mods["cf"] == ModuleSet(map="cfmap")
    assert mods["orion"] == ModuleSet(map="orion", detector="grounded", explore=True, memory=True)
    assert mods["cow"].describe() == "no map, saliency detection, exploration, no memory"
    # ORION's ablations (the paper's Table II): ORION's set with one module taken away (the detector: CoW's CLIP one),
    # evaluated only when named
    orion = mods["orion"]
    assert mods["orion_wo_mem"] == ModuleSet(map="orion", detector="grounded", explore=True)
    assert mods["orion_wo_exp"] == ModuleSet(map="orion", detector="grounded", memory=True)
    assert mods["orion_wo_det"] == ModuleSet(map="orion", detector="saliency", explore=True, memory=True)
    assert mods["orion_wo_map"] == ModuleSet(detector="grounded", explore=True, memory=True)
    assert not any(AGENTS[n].by_default for n in ablations) and AGENTS["orion"].by_default
    assert not AGENTS["orion_wo_mem"].persistent_memory and AGENTS["orion_wo_map"].persistent_memory
    assert all(sum(a != b for a, b in zip(astuple(mods[n]), astuple(orion))) == 1 for n in ablations)


def test_a_detector_without_exploration_looks_around_where_it_stands(ctx):
    """The paper's "ORION w/o exp" keeps the 360 deg spin: with nothing left to try, a method with a detector and no
    exploration looks around once where it stands (no frontier search) and gives up when that shows nothing new."""
    class Spinner(ModularAgent):
        modules = ModuleSet(detector="grounded")

    goal, run, _ = episode(ctx, "orion")
    agent = Spinner(ctx.params)
    m = run.modules
    m.detector = "grounded"
    steps = run.body.steps
    assert agent.next_candidate(m, SearchState(name="bicycle"), "bicycle") is None  # nothing of that here
    spin = run.body.steps - steps
    assert spin == round(360 / ctx.turn_deg) and m.frontier() is not None  # one spin, no frontier walked to
    assert agent.next_candidate(m, SearchState(name="bicycle"), "bicycle") is None and run.body.steps == steps + spin


def test_cow_detects_with_its_own_detector(ctx):
    goal, run, agent = episode(ctx, "cow")
    from orion_eval.episode import EpisodeOver

    try:
        agent.run(run.modules, "", goal.name)
    except EpisodeOver:
        pass
    assert run.modules.detector == "saliency"
    assert any(k[2] == "saliency" for k in ctx._det_cache)
    _, run2, orion = episode(ctx, "orion")
    assert run2.modules.detector == "grounded"


def test_procedural_point_is_walked_to_and_searched_around(ctx):
    goal, run, agent = episode(ctx, "vlmap")
    m = run.modules
    st = SearchState(name=goal.name)
    oid = m.retrieve_map(goal.name, "vlmap")[0][0]
    x0, y0, yaw0 = m.pose
    agent.update(m, st, ParsedFeedback(destination=(90.0, 2.0)), oid, goal.name)
    moved = math.hypot(m.pose[0] - x0, m.pose[1] - y0)
    assert run.body.steps > 0 and moved > 0.5
    assert len(st.focus) == 1 and np.allclose(st.focus[0][0], m.pose[:2])
    assert st.spin_at is None  # no detector: the map candidates are ranked by distance to the end point
    ids = [t[0] for t in m.retrieve_map(goal.name, "vlmap")]
    ranked = agent.ranked(m, st, ids)
    d = [st.focus_distance(m.objects[i].center_xy) for i in ranked]
    assert d == sorted(d) or np.allclose(np.round(d, 2), sorted(np.round(d, 2)))


def test_a_route_is_followed_to_its_end_and_a_detector_looks_there(ctx):
    goal, run, agent = episode(ctx, "orion")
    m = run.modules
    st = SearchState(name=goal.name)
    oid = m.retrieve_map(goal.name, ctx.params.eval.orion_map)[0][0]
    agent.update(m, st, ParsedFeedback(route=[("turn", 90.0), ("forward", 1.0)]), oid, goal.name)
    assert run.body.actions[:6] == [2] * 6  # six 15 deg left turns
    assert np.allclose(st.spin_at, m.pose[:2]) and np.allclose(st.focus[0][0], m.pose[:2])


def test_corrective_feedback_helps_only_through_memory(ctx):
    for method, remembered in (("vlmap", False), ("orion", True)):
        goal, run, agent = episode(ctx, method)
        m = run.modules
        which = agent.map_name()
        oid = m.retrieve_map(goal.name, which)[0][0]
        plain, corrected = SearchState(name=goal.name), SearchState(name=goal.name)
        agent.update(m, plain, ParsedFeedback(), oid, goal.name)
        before = {k: dict(v) for k, v in m.memory.maps.items()}
        agent.update(m, corrected, ParsedFeedback(corrected_as="Bob's chair"), oid, goal.name)
        assert vars(plain) == vars(corrected)  # the search itself does not change
        assert (m.memory.maps["pos"] != before["pos"]) == remembered
        assert bool(m.retrieve_memory("Bob's chair")[0]) == remembered


def test_landmarks_are_located_with_the_methods_own_modules(ctx):
    goal, run, agent = episode(ctx, "vlmap")
    m = run.modules
    phrase = next(o for o in ("bed", "table", "couch", "chair", "cabinet") if m.retrieve_map(o, "vlmap"))
    st = SearchState(name=goal.name)
    hints = agent.locate_landmarks(m, st, [phrase])
    assert len(hints) == 1 and len(hints[0]) == len(m.retrieve_map(phrase, "vlmap"))
    assert run.body.steps == 0  # the map answers without moving
    oid = m.retrieve_map(goal.name, "vlmap")[0][0]
    agent.update(m, st, ParsedFeedback(landmarks=[phrase]), oid, goal.name)
    assert len(st.focus) == 1 and st.spin_at is None
    goal, run, cow = episode(ctx, "cow")
    run.modules.detector = "saliency"
    st = SearchState(name=goal.name)
    m = run.modules
    hints = cow.locate_landmarks(m, st, [phrase, "bicycle"])
    steps = run.body.steps
    assert steps >= 24  # the detector has to look: one spin for both, exploration when neither is seen
    again = cow.locate_landmarks(m, st, [phrase, "bicycle"])
    assert run.body.steps == steps and len(again) == len(hints)  # each landmark is looked for once per episode
    assert all(np.array_equal(a, b) for a, b in zip(again, hints)) and set(st.landmarks) == {phrase, "bicycle"}
    st = SearchState(name=goal.name)
    oid = m.register(m.pose[:2], np.array([0]), "detect")
    cow.update(m, st, ParsedFeedback(landmarks=[phrase], route=[("forward", 0.5)]), oid, goal.name)
    # with a route as well: one spin at the route's end looks for the landmark and the goal together; either the
    # goal is in sight (tried first), or the landmark seen nearest the route's end is a second hint to look around at
    assert st.spotted or st.landmarks[phrase] is not None
    if st.landmarks[phrase] is not None:
        assert len(st.focus) == 2 and len(st.focus[1]) == 1 and st.spin_at is not None
    else:
        assert len(st.focus) == 1 and all(not m.objects[i].source.endswith("map") for i in st.spotted)


def test_a_route_picks_the_landmark_instance_at_its_end(ctx):
    goal, run, agent = episode(ctx, "vlmap")
    m = run.modules
    phrase = next(o for o in ("chair", "table", "cabinet", "bed", "couch") if len(m.retrieve_map(o, "vlmap")) >= 2)
    every = np.asarray([m.objects[t[0]].center_xy for t in m.retrieve_map(phrase, "vlmap")])
    st = SearchState(name=goal.name)
    oid = m.retrieve_map(goal.name, "vlmap")[0][0]
    agent.update(m, st, ParsedFeedback(landmarks=[phrase], route=[("forward", 0.5)]), oid, goal.name)
    end = np.asarray(m.pose[:2])
    assert len(st.focus) == 2 and np.allclose(st.focus[0], end)
    # of the map's instances of the landmark, only the one nearest the route's end is kept
    assert len(st.focus[1]) == 1 and np.allclose(st.focus[1][0], every[np.argmin(np.hypot(*(every - end).T))])
    alone = SearchState(name=goal.name)
    agent.update(m, alone, ParsedFeedback(landmarks=[phrase]), oid, goal.name)
    assert len(alone.focus) == 1 and len(alone.focus[0]) == len(every)  # without a route: every instance


def test_a_map_without_a_detector_tries_next_to_the_landmark_then_asks_at_it(ctx):
    """VLMap cannot look around a landmark: the name's candidates next to it come first (footprints within the
    user's own "next to" radius), then the landmark itself (walked to, asked there), then the other candidates;
    after a route, only the instance of the landmark nearest the route's end is asked at."""
    goal, run, agent = episode(ctx, "vlmap")
    m = run.modules
    phrase = next(o for o in ("bed", "table", "couch", "chair", "cabinet")
                  if len(m.retrieve_map(o, "vlmap")) >= 2 and o not in goal.name)
    marks = [t[0] for t in m.retrieve_map(phrase, "vlmap")]
    oid = m.retrieve_map(goal.name, "vlmap")[0][0]
    radius = ctx.params.goals.landmark_radius_m
    for route, asked in (([], len(marks)), ([("forward", 0.5)], 1)):
        st = SearchState(name=goal.name)
        agent.update(m, st, ParsedFeedback(landmarks=[phrase], route=route), oid, goal.name)
        ids = agent.map_candidates(m, st, "vlmap")
        tiers = agent.next_to_landmarks(m, st, ids)
        near = [i for i in ids if any(agent.footprint_gap(m, i, j) <= radius for j in marks
                                      if any(np.allclose(m.objects[j].center_xy, p) for p in st.focus[-1]))]
        at = [i for i in tiers if i in marks and i not in ids]
        rest = [i for i in ids if i not in near]
        assert sorted(tiers) == sorted(near + at + rest) and 1 <= len(at) <= asked
        tier = {**dict.fromkeys(rest, 2), **dict.fromkeys(at, 1), **dict.fromkeys(near, 0)}
        if not route:
            assert tiers == near + at + rest
            continue
        # after a route its end comes first, in whole metres; within a metre: next to the landmark, at it, the rest
        metres = [round(float(np.hypot(*(m.objects[i].center_xy - st.route_end)))) for i in tiers]
        assert metres == sorted(metres)
        assert all(tier[a] <= tier[b] for (a, ma), (b, mb) in zip(zip(tiers, metres), zip(tiers[1:], metres[1:]))
                   if ma == mb)
    assert all(agent.footprint_gap(m, i, i) == 0.0 for i in marks)
    assert agent.footprint_gap(m, marks[0], marks[1]) > 0.0
    # a method with a detector looks around the landmark instead (test_a_method_with_map_and_detector_...)
    goal, run, orion = episode(ctx, "orion")
    st, m = SearchState(name=goal.name), run.modules
    oid = m.retrieve_map(goal.name, orion.map_name())[0][0]
    orion.update(m, st, ParsedFeedback(landmarks=[phrase]), oid, goal.name)
    assert st.spin_at is not None


def test_a_sighted_landmark_instance_the_user_rejected_next_to_is_passed_over(ctx):
    """Without a map a landmark is the instance a spin happened to see; a "No" next to it with the same landmark
    named again means another instance: that one is passed over and the landmark looked for again. A map, which
    knows every instance, keeps them all (the hints rank them)."""
    goal, run, cow = episode(ctx, "cow")
    m = run.modules
    st = SearchState(name=goal.name)
    phrase = next(o for o in ("bed", "table", "couch", "chair", "cabinet")
                  if o not in goal.name and cow.locate_landmarks(m, st, [o]))
    first = list(st.landmark_ids[phrase])
    assert first and len(st.landmarks[phrase]) == len(first)
    wrong = first[0]
    cow.update(m, st, ParsedFeedback(landmarks=[phrase]), wrong, goal.name)
    assert st.passed[phrase] >= {wrong}
    assert wrong not in st.landmark_ids.get(phrase, [])  # looked for again, that instance passed over
    if st.landmarks.get(phrase) is not None:
        assert all(not np.allclose(p, m.objects[wrong].center_xy) for p in st.landmarks[phrase])
    goal, run, vlmap = episode(ctx, "vlmap")
    m = run.modules
    st = SearchState(name=goal.name)
    every = [t[0] for t in m.retrieve_map(phrase, "vlmap")]
    if every:
        vlmap.update(m, st, ParsedFeedback(landmarks=[phrase]), every[0], goal.name)
        assert not st.passed and st.landmark_ids[phrase] == every


def fake_object(m, ctx, xy) -> int:
    """A found object of one grid cell at ``xy`` (what a spin or an exploration would have registered)."""
    rc = ctx.grid.world_to_cell(np.asarray(xy, np.float64))
    return m.register(np.asarray(xy, np.float64), np.asarray([rc[0] * ctx.grid.cols + rc[1]], np.int64), "detect")


def test_after_a_route_a_maps_landmark_tiers_order_within_each_metre_of_its_end(ctx):
    """A map without a detector told of a landmark tries the candidates next to it first; after a route, the route's
    end still comes first (in whole metres), so a candidate by a landmark instance 3 m from the end does not draw the
    search away from one at the end. A candidate that is the landmark instance itself is not next to it: it is asked
    at as the landmark, after the candidates next to it."""
    goal, run, vlmap = episode(ctx, "vlmap")
    m = run.modules
    here = np.asarray(m.pose[:2], np.float64)
    end = here + np.array([1.0, 0.0])
    mark = fake_object(m, ctx, here + np.array([4.0, 0.0]))
    by_mark = fake_object(m, ctx, here + np.array([4.0, 0.8]))  # apart (MERGE_M), next to it
    at_end = fake_object(m, ctx, end + np.array([0.0, 0.3]))
    assert len({mark, by_mark, at_end}) == 3
    st = SearchState(name=goal.name, marks=[mark], focus=[m.objects[mark].center_xy[None]])
    assert vlmap.next_to_landmarks(m, st, [by_mark, at_end]) == [by_mark, mark, at_end]
    st.route_end, st.focus = end, [end[None], m.objects[mark].center_xy[None]]
    assert vlmap.next_to_landmarks(m, st, [by_mark, at_end]) == [at_end, by_mark, mark]
    st.route_end, st.focus = None, [m.objects[mark].center_xy[None]]
    assert vlmap.next_to_landmarks(m, st, [mark, by_mark])[:2] == [by_mark, mark]


def test_a_sighted_landmark_is_passed_over_only_once_its_neighbourhood_is_searched(ctx):
    """A "No" next to a sighted landmark instance says that object is not the goal; the goal may still be another
    object next to the same instance. The instance is passed over (and the landmark looked for again) only when
    nothing seen next to it is left to ask about and no side of it is left to look from."""
    goal, run, cow = episode(ctx, "cow")
    m = run.modules
    here = np.asarray(m.pose[:2], np.float64)
    bed = fake_object(m, ctx, here + np.array([1.5, 0.0]))
    asked = fake_object(m, ctx, here + np.array([1.5, 0.8]))  # apart from the bed (MERGE_M), next to it
    other = fake_object(m, ctx, here + np.array([1.5, -0.9]))
    st = cow.state(goal.name)
    st.landmark_ids["the bed"], st.landmarks["the bed"] = [bed], cow.places(m, [bed])
    st.reject(m.objects[asked])
    st.spotted = [asked, other]  # the other one seen next to the bed is still to be asked about
    cow.pass_over_sighted(m, st, ["the bed"], asked)
    assert st.landmark_ids["the bed"] == [bed] and not st.passed
    st.spotted = [asked]
    st.around = [m.objects[bed].center_xy, [here + np.array([3.0, 0.0])]]  # one side still to look from
    cow.pass_over_sighted(m, st, ["the bed"], asked)
    assert st.landmark_ids["the bed"] == [bed] and not st.passed
    st.around[1].clear()
    cow.pass_over_sighted(m, st, ["the bed"], asked)
    assert st.passed["the bed"] == {bed} and st.landmarks.get("the bed") is None  # looked for again


def test_without_a_map_a_goal_sighting_away_from_every_landmark_is_held(ctx):
    """Told the goal is next to a landmark it has not found, CoW explores for the landmark: what it sees of the goal
    on the way is not asked about at once. Once the landmark is found, a sighting next to it is tried first and one
    away from it is held (tried once the landmark's neighbourhood shows nothing, before exploring further); when no
    landmark is found, every sighting is tried."""
    for found in (True, False):
        goal, run, cow = episode(ctx, "cow")
        m = run.modules
        here = np.asarray(m.pose[:2], np.float64)
        wrong = fake_object(m, ctx, here + np.array([0.0, -1.5]))
        in_spin = fake_object(m, ctx, here + np.array([0.3, 0.0]))
        on_way = fake_object(m, ctx, here + np.array([-2.0, 0.0]))
        beside = fake_object(m, ctx, here + np.array([3.0, 0.8]))
        bed = fake_object(m, ctx, here + np.array([3.0, 0.0]))
        st = cow.state(goal.name)
        st.reject(m.objects[wrong])
        m.look_around_for = lambda strs: {s: [(in_spin, 1.0, 0.0)] if s in st.queries else [] for s in strs}
        hits = [(st.queries[0], on_way), (st.queries[0], in_spin), (st.queries[0], beside)]
        hits += [("the bed", bed)] if found else []

        def search(strs, skip=None, near=None):
            while hits:  # the exploration's sightings in turn, less those it is told to pass over
                s, i = hits.pop(0)
                if s in strs and not (skip or {}).get(s, lambda _: False)(i):
                    return s, i
            return None

        m.search_objects = search
        cow.update(m, st, ParsedFeedback(landmarks=["the bed"]), wrong, goal.name)
        if found:
            assert st.landmark_ids["the bed"] == [bed]
            assert st.spotted == [beside] and sorted(st.held) == sorted([in_spin, on_way])
            assert np.allclose(st.spin_at, m.objects[bed].center_xy)  # the goal is looked for around the bed
        else:
            assert st.landmarks.get("the bed") is None and not st.held
            assert sorted(st.spotted) == sorted([in_spin, on_way, beside])


def test_a_description_is_the_detectors_prompt_not_a_map_query(ctx):
    """As in the paper's reference code, the map is asked for the goal's name only; the description goes to the
    detector (its spins look for the description, then the name). A method with only a map gains nothing from it."""
    goal, run, agent = episode(ctx, "cf")
    m = run.modules
    st = SearchState(name=goal.name)
    oid = m.retrieve_map(goal.name, "cfmap")[0][0]
    before = agent.map_candidates(m, st, "cfmap")
    agent.update(m, st, ParsedFeedback(description="red chair made of wood"), oid, goal.name)
    assert run.body.steps == 0
    assert st.queries == ["red chair made of wood", goal.name]  # what a detector looks for, the description first
    assert agent.map_candidates(m, st, "cfmap") == before
    assert ("cfmap", "red chair made of wood") not in ctx._map_cache  # the map was never asked for the description


def test_a_detectors_spin_looks_for_the_description_and_the_name(ctx):
    """The description narrows what the detector looks for, it does not replace it: at the hinted place one spin
    detects both, the described objects first, and what is seen only as the name is still tried (after them)."""
    from orion_eval.world import Body

    goal, run, agent = episode(ctx, "orion")
    obj = ctx.scene.goals.objects[goal.object_keys[0]]
    ep = ctx.scene.routes.for_goal(goal.id)[0]
    route = ctx.route_to_goal(ctx.view_planner, ep.start, goal, key="t", face_xy=np.asarray(obj.mass_center))
    run.body = Body(*ep.start)
    for a in route.actions.tolist():  # walk to where the goal is in view
        if a == 0:
            break
        ctx.world.act(run.body, a)
    m = run.modules
    m.detector = "grounded"
    named = [t[0] for t in m.look_around_for([goal.name])[goal.name]]
    assert named, "the goal is seen from where its route ends"
    steps = run.body.steps
    st = SearchState(name=goal.name, description="purple zebra made of glass")
    st.spin_at = np.asarray(m.pose[:2], np.float64)
    agent.look_at_focus(m, st)
    assert run.body.steps > steps  # a new query: one more spin here
    assert set(named) <= set(st.spotted)  # seen as the name, not as the description: still a candidate
    described = [t[0] for t in m.look_around_for([st.description])[st.description]]
    assert set(st.spotted[: len(described)]) == set(described)


def test_a_detector_reads_the_described_colour_off_the_object_in_view(tiny_scene):
    """check_attributes with the simulated detector: seen as the goal's class with its own colour -> True; seen as
    the class but with another colour -> False (passed over without a question). Only the object's own sightings
    count: with another known object nearer the sighting (a neighbour of the goal's class), neither (None)."""
    from orion_eval.world import Body

    ws, params = tiny_scene
    simulated = params.model_copy(update={"eval": params.eval.model_copy(update={"detect_encoder": "simulated_lseg"})})
    ctx = SceneContext(Scene(ws, simulated, "tiny", STAGES, check=True))
    assert ctx.detector is not None

    colours = ("red", "blue", "green", "white", "black", "yellow")
    readings, neighbours, spins_seen = [], 0, 0
    for gi in range(len([g for g in ctx.scene.goals.goals if ctx.scene.routes.for_goal(g.id)])):
        goal, run, agent = episode(ctx, "orion", gi)
        obj = ctx.scene.goals.objects[goal.object_keys[0]]
        own = " ".join(obj.color_name.lower().split())
        other = next(c for c in colours if c != own)
        ep = ctx.scene.routes.for_goal(goal.id)[0]
        route = ctx.route_to_goal(ctx.view_planner, ep.start, goal, key="t", face_xy=np.asarray(obj.mass_center))
        body = Body(*ep.start)
        for a in route.actions.tolist():
            if a == 0:
                break
            ctx.world.act(body, a)
        run.body = body
        m = run.modules
        cells = np.flatnonzero(ctx.footprint_mask((obj.key,)).reshape(-1))
        oid = m.register(np.asarray(obj.mass_center, np.float64), cells, "detect")
        right = m.check_attributes(oid, obj.cls, f"{own} {obj.cls}")
        wrong = m.check_attributes(oid, obj.cls, f"{other} {obj.cls}")
        seen = any(np.isin(d.cells, cells).any() for d in ctx.detect(m.pose, obj.cls))
        readings.append((seen, right, wrong))
        if seen:  # one draw per view and object: seen as its class, it is seen with its own colour, not another
            assert right is True and wrong is False
            sighting = next(d for d in ctx.detect(m.pose, obj.cls) if np.isin(d.cells, cells).any())
            if np.linalg.norm(sighting.center_xy - m.objects[oid].center_xy) > 1e-3:
                # another object known to be where the sighting is: the sighting is that object's, not the goal's
                m.objects[2] = FoundObject(2, sighting.center_xy.copy(), sighting.cells, "detect")
                assert m.check_attributes(oid, obj.cls, f"{other} {obj.cls}") is None
                assert m.check_attributes(oid, obj.cls, f"{own} {obj.cls}") is None
                del m.objects[2]
                neighbours += 1
        # the same reading from a look around there (read_around): its four views, not one facing the goal
        m.look_around_for([obj.cls, f"{own} {obj.cls}", f"{other} {obj.cls}"])  # one spin for the three
        around = [m.read_around(oid, obj.cls, f"{c} {obj.cls}") for c in (own, other)]  # remembered: no steps
        # the grounded detector reads each object's own colour: the goal's own never reads wrong, another never right
        assert around[0] is not False and around[1] is not True
        spins_seen += around[0] is True
    assert any(r[0] for r in readings) and spins_seen
    assert neighbours, "no sighting away from the registered centre: the neighbour rule was not exercised"


def test_an_explorer_searches_on_while_frontiers_are_left(tiny_scene):
    """eval.explore_max_targets bounds one search, not the episode: with nothing to find, CoW explores until no
    frontier is left (or its steps run out), it does not give up after one search."""
    from orion_eval.episode import EpisodeOver

    ws, params = tiny_scene
    few = params.model_copy(update={"eval": params.eval.model_copy(update={"explore_max_targets": 1})})
    small = SceneContext(Scene(ws, few, "tiny", STAGES, check=True))
    goal, run, agent = episode(small, "cow")
    m = run.modules
    m.detector = "saliency"
    one = SceneContext(Scene(ws, few, "tiny", STAGES, check=True))
    _, run1, _ = episode(one, "cow")
    run1.modules.detector = "saliency"
    assert run1.modules.search_object("bicycle") is None
    one_search = run1.body.steps
    try:
        assert agent.next_candidate(m, SearchState(name="bicycle"), "bicycle") is None
        assert m.frontier() is None  # gave up only with nothing left to explore
    except EpisodeOver:
        pass  # or ran out of steps exploring
    assert run.body.steps > one_search


def test_after_a_route_the_map_candidates_rank_by_distance_to_its_end(ctx):
    goal, run, agent = episode(ctx, "vlmap")
    m = run.modules
    st = SearchState(name=goal.name, description="white " + goal.name)
    oid = m.retrieve_map(goal.name, "vlmap")[0][0]
    agent.update(m, st, ParsedFeedback(route=[("forward", 1.0)]), oid, goal.name)
    assert np.allclose(st.route_end, m.pose[:2])
    ids = agent.map_candidates(m, st, "vlmap")
    ends = [round(float(np.hypot(*(m.objects[i].center_xy - st.route_end)))) for i in ids]
    assert ids and ends == sorted(ends)  # the name's candidates, the route's end first
    assert set(ids) >= {t[0] for t in m.retrieve_map(goal.name, "vlmap")}


def orion_told_landmark(ctx, route=None):
    """ORION (map + detector) after a "No" naming a landmark its map retrieves (and ``route``, when given):
    ``(run, agent, search state, landmark phrase)``."""
    goal, run, agent = episode(ctx, "orion")
    m, which = run.modules, agent.map_name()
    phrase = next(o for o in ("bed", "table", "couch", "chair", "cabinet") if m.retrieve_map(o, which))
    st = SearchState(name=goal.name)
    oid = m.retrieve_map(goal.name, which)[0][0]
    agent.update(m, st, ParsedFeedback(landmarks=[phrase], route=route or []), oid, goal.name)
    return run, agent, st, phrase


def test_a_method_with_map_and_detector_looks_around_its_landmark(ctx):
    run, agent, st, phrase = orion_told_landmark(ctx)
    m, which = run.modules, agent.map_name()
    assert run.body.steps == 0  # the map says where the landmark is
    places = [m.objects[t[0]].center_xy for t in m.retrieve_map(phrase, which)]
    assert st.spin_at is not None and any(np.allclose(st.spin_at, p) for p in places)  # the detector looks there


def test_after_a_route_a_detector_looks_around_its_end_before_the_landmark(ctx):
    """Mixed feedback combines the kinds: a route with landmarks is searched as the route alone would be (a look
    around at its end) and, when that sees nothing, around the landmark instance nearest the end."""
    run, agent, st, _ = orion_told_landmark(ctx, route=[("forward", 0.5)])
    m = run.modules
    end = np.asarray(m.pose[:2])
    assert np.allclose(st.spin_at, end) and np.allclose(st.spin_then, st.focus[1][0])
    start = run.body.steps
    agent.look_at_focus(m, st)
    turns = int(round(360.0 / ctx.turn_deg))
    assert run.body.actions[start:start + turns] == [LEFT] * turns  # the first look around is at the route's end
    assert st.spin_at is None and st.spin_then is None
    far = float(np.hypot(*(np.asarray(m.pose[:2]) - end))) > ctx.params.eval.reject_radius_m
    # it went on to the landmark only when the route's end showed nothing
    assert far or st.spotted or np.hypot(*(st.focus[1][0] - end)) <= ctx.params.eval.reject_radius_m
    if far:
        assert run.body.actions[-turns:] == [LEFT] * turns


def test_the_map_is_trusted_until_it_has_been_wrong_for_several_turns(ctx):
    """ORION asks about its map's candidate as VLMap does; only once the user has rejected
    ``double_check_after`` of the map's candidates does it double-check them in the ego view before asking."""
    goal, run, agent = episode(ctx, "orion")
    m = run.modules
    checked = []
    real = m.double_check
    m.double_check = lambda oid: checked.append(oid) or real(oid)
    st = SearchState(name=goal.name)
    first = agent.next_candidate(m, st, goal.name)
    assert checked == [] and m.objects[first].source == agent.map_name()  # asked about as the map gave it
    agent.update(m, st, ParsedFeedback(), first, goal.name)
    assert st.map_wrong == 1  # the user said "No" to the map's candidate
    # a rejected detection is not the map's mistake
    seen = m.register(np.array([-50.0, -50.0]), np.array([0]), "detect")
    agent.update(m, st, ParsedFeedback(), seen, goal.name)
    assert st.map_wrong == 1
    assert agent.double_check_after == 2
    _, run, agent = episode(ctx, "orion")  # a fresh episode (the "No" above is in this one's memory)
    m, real = run.modules, run.modules.double_check
    m.double_check = lambda oid: checked.append(oid) or real(oid)
    st2 = SearchState(name=goal.name, map_wrong=agent.double_check_after)
    again = agent.next_candidate(m, st2, goal.name)
    # wrong twice: the map's first candidate (the same one: ids follow the map's order) is double-checked first
    assert checked and checked[0] == first
    assert again == first or first in st2.deferred


def test_a_saliency_localiser_holds_one_prompt():
    """CoW's Grad-CAM relevance is computed for the one prompt the agent holds: the name, then the description (which
    names the class); the grounded detector is asked for the description and the name."""
    cow, orion, wo_det = (build_agent(n, None) for n in ("cow", "orion", "orion_wo_det"))
    for agent, one in ((cow, True), (orion, False), (wo_det, True)):
        st = agent.state("Alice's chair")
        assert st.one_prompt is one and st.queries == ["Alice's chair"]
        st.description = "red chair made of wood"
        assert st.queries == (["red chair made of wood"] if one else ["red chair made of wood", "Alice's chair"])


def test_a_landmark_not_found_is_looked_for_again_where_the_exploration_left_off(tiny_scene):
    """Without a map, a landmark the agent has not found is looked for again each time the user names it: the spin
    where it stands is remembered (no steps), and the exploration goes on from the frontiers it left."""
    ws, params = tiny_scene
    few = params.model_copy(update={"eval": params.eval.model_copy(update={"explore_max_targets": 1})})
    small = SceneContext(Scene(ws, few, "tiny", STAGES, check=True))
    goal, run, cow = episode(small, "cow")
    m = run.modules
    m.detector = "saliency"
    st = cow.state(goal.name)
    assert cow.locate_landmarks(m, st, ["bicycle"]) == []
    first = run.body.steps
    assert first >= 24 and st.landmarks["bicycle"] is None
    left = m.frontier()
    cow.locate_landmarks(m, st, ["bicycle"])
    assert left is None or run.body.steps > first  # on to the next frontier, not the same spin again


def test_the_exploration_starts_over_when_its_target_changes(ctx):
    """CoW's exploration resets its frontier map when its search target changes (navchat's search_object for CoW): the
    goal's search after a landmark was found, or after a description replaced CoW's one prompt, starts over from where
    the agent stands; a phrase-grounding detector's target stays the goal's name whatever its prompt (ORION)."""
    goal, run, cow = episode(ctx, "cow")
    m = run.modules
    restarts = []
    m.restart_exploration = lambda: restarts.append(run.body.steps)
    st = cow.state(goal.name)
    cow.explore_for(m, st, st.goal_target)
    cow.explore_for(m, st, st.goal_target)
    assert restarts == [] and st.target == (goal.name,)  # the first search, then the same target: no restart
    st.description = "red chair made of wood"
    cow.explore_for(m, st, st.goal_target)
    assert len(restarts) == 1 and st.target == ("red chair made of wood",)
    orion = build_agent("orion", ctx.params)
    sto = orion.state(goal.name)
    orion.explore_for(m, sto, sto.goal_target)
    sto.description = "red chair made of wood"
    orion.explore_for(m, sto, sto.goal_target)
    assert len(restarts) == 1 and sto.target == (goal.name,)
    # a landmark found (here seen by the spin where the agent stands) is what the exploration last searched for
    oid = m.register(np.asarray(m.pose[:2]) + 1.0, np.zeros(0, np.int64), "detect")
    m.look_around_for = lambda strs: {s: [(oid, 1.0, 0.0)] if s == "the bed" else [] for s in strs}
    cow.find_landmarks(m, st, ["the bed"], ["the bed"])
    assert st.landmark_ids["the bed"] == [oid] and st.target == ("the bed",)
    cow.explore_for(m, st, st.goal_target)
    assert len(restarts) == 2 and st.target == ("red chair made of wood",)
    # a landmark not found leaves the goal's search where it was
    m.look_around_for = lambda strs: {s: [] for s in strs}
    m.search_objects = lambda *a, **k: None
    cow.find_landmarks(m, st, ["the sofa"], ["the sofa"])
    assert st.landmarks["the sofa"] is None and st.target == ("red chair made of wood",)


def test_cow_looks_for_the_goal_from_the_sides_of_a_landmark_it_found(ctx):
    """A landmark CoW found by exploring is looked around at, and when that spin shows nothing of the goal, from the
    landmark's other sides in turn until the goal is seen (the floor one spin from one side could not see); a method
    that places the landmark on its map (ORION) looks around at it once, as before."""
    goal, run, cow = episode(ctx, "cow")
    m = run.modules
    m.detector = "saliency"
    g = ctx.grid
    here = np.asarray(m.pose[:2], np.float64)
    mark = np.asarray(goal.mass_center[:2], np.float64)  # the landmark stands where this scene's goal does

    def cells(xy):
        rc = g.world_to_cell(np.asarray(xy, np.float64))
        return np.asarray([rc[0] * g.cols + rc[1]], np.int64)

    bed = m.register(mark, cells(mark), "detect")
    sides = m.sides_of(mark, here)
    assert sides, "the tiny scene's goal has navigable floor round it"
    hidden = sides[-1]  # the goal stands on the landmark's last side: seen only from there
    target = m.register(mark + 0.8 * (hidden - mark) / np.linalg.norm(hidden - mark), cells(hidden), "detect")
    spins, saw = [], []

    def look(strs):
        spins.append(np.asarray(m.pose[:2], np.float64))
        seen = float(np.hypot(*(spins[-1] - hidden))) <= ctx.params.eval.goto_stop_radius_m + 0.3
        saw.append(seen)
        return {s: [(bed, 1.0, 0.0)] if s == "the bed" else [(target, 1.0, 0.0)] if seen and s != "the bed" else []
                for s in strs}

    m.look_around_for = look
    st = cow.state(goal.name)
    wrong = m.register(here + 0.1, cells(here), "detect")
    cow.update(m, st, ParsedFeedback(landmarks=["the bed"]), wrong, goal.name)
    assert st.landmark_ids["the bed"] == [bed] and np.allclose(st.spin_at, mark)
    assert np.allclose(st.around[0], mark) and len(st.around[1]) == len(sides)
    cow.look_at_focus(m, st)
    assert st.spotted == [target]
    # the spin that found the landmark and the one at it saw nothing of the goal; the looks from its sides went on
    # until one did, and stopped there
    assert len(spins) >= 3 and saw[:2] == [False, False] and saw[-1] and not any(saw[2:-1])
    assert all(float(np.hypot(*(p - mark))) <= side_reach(ctx) for p in spins[2:])  # every look was round it

    # a goal seen by the spin at the landmark is tried at once: no side is walked to
    _, run2, cow2 = episode(ctx, "cow")
    m2 = run2.modules
    target2 = m2.register(m.objects[target].center_xy, m.objects[target].cells, "detect")
    looks = []
    m2.look_around_for = lambda strs: looks.append(m2.pose) or {s: [(target2, 1.0, 0.0)] for s in strs}
    st2 = cow2.state(goal.name)
    st2.spin_at, st2.around = mark, [mark, list(sides)]
    cow2.look_at_focus(m2, st2)
    assert st2.spotted == [target2] and len(looks) == 1 and len(st2.around[1]) == len(sides)

    run_o, orion, st_o, _ = orion_told_landmark(ctx)
    assert st_o.around == [] and st_o.spin_at is not None  # the map's landmark: one look around at it


def side_reach(ctx) -> float:
    """How far from a landmark's centre a look from its side can be taken: the side's point (SIDE_M) and the distance
    a walk to a point stops short of it (eval.goto_stop_radius_m), plus a step of slack."""
    from orion_eval.modules import SIDE_M

    return SIDE_M + ctx.params.eval.goto_stop_radius_m + ctx.step_m




def test_a_sighted_landmark_seen_in_another_colour_is_passed_over_and_looked_for_again(tiny_scene):
    """CoW looks around at the landmark instance it sighted, and that spin also reads it by the colour and material
    the user said ("the white bed made of wood"), as a described goal is checked: when it shows nothing of the goal
    and saw that bed as a bed but not as the said one, the bed is passed over and the landmark looked for again (here
    the spin finds the other bed, which becomes the place to look around at, read in turn); one that reads right, or
    cannot be read, is kept (its sides looked from as before). A landmark named by its class alone has nothing to
    check it by."""
    ws, params = tiny_scene
    simulated = params.model_copy(update={"eval": params.eval.model_copy(update={"detect_encoder": "simulated_lseg"})})
    sim = SceneContext(Scene(ws, simulated, "tiny", STAGES, check=True))
    phrase = "the white bed made of wood"
    assert sim.object_phrase(phrase) == "bed"
    assert sim.object_phrase("the bed") is None and sim.object_phrase("Alice's bed") is None
    reach = sim.params.eval.goto_stop_radius_m + sim.step_m

    def told(right: bool):
        goal, run, cow = episode(sim, "cow")
        m = run.modules
        m.detector = "saliency"
        here = np.asarray(m.pose[:2], np.float64)

        def cell(xy):
            rc = sim.grid.world_to_cell(np.asarray(xy, np.float64))
            return np.asarray([rc[0] * sim.grid.cols + rc[1]], np.int64)

        near, far = here + 0.3, here + np.array([1.5, 0.0])
        first, other = m.register(near, cell(near), "detect"), m.register(far, cell(far), "detect")
        spins = []
        st = cow.state(goal.name)

        def look(strs):
            # from afar the first bed is taken for the said one; close, it reads as the said one only when ``right``;
            # once it is passed over, the next spin finds the other bed, which reads right
            spins.append(np.asarray(m.pose[:2], np.float64))
            bed = other if first in st.passed.get(phrase, set()) else first
            said = len(spins) == 1 or bed == other or right
            return {s: [(bed, 1.0, 0.0)] if s == "bed" or (s == phrase and said) else [] for s in strs}

        m.look_around_for = look
        wrong = m.register(here - 0.4, cell(here - 0.4), "detect")
        cow.update(m, st, ParsedFeedback(landmarks=[phrase]), wrong, goal.name)
        assert st.landmark_ids[phrase] == [first] and st.sighted[1:] == (phrase, first)
        cow.look_at_focus(m, st)
        return st, spins, (first, other), (near, far)

    st, spins, (first, other), (near, far) = told(right=False)
    assert st.passed[phrase] == {first} and st.landmark_ids[phrase] == [other]
    # the passed bed's place is no longer a hint, the other bed's is; the next look around was at that one
    hints = np.vstack(st.focus)
    assert not np.any(np.all(np.isclose(hints, near), axis=1)) and np.any(np.all(np.isclose(hints, far), axis=1))
    # spins: the one that sighted the first bed, the one at it, the one that found the other, the one at that
    assert len(spins) >= 4 and float(np.hypot(*(spins[3] - far))) <= reach
    assert st.sighted is None  # read once, there
    st, spins, (first, _), _ = told(right=True)
    assert not st.passed.get(phrase) and st.landmark_ids[phrase] == [first]
    assert all(float(np.hypot(*(p - near))) <= side_reach(sim) for p in spins[1:])  # it stayed round the first bed
