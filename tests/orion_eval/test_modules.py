"""The ORION modules on the tiny scene: map retrieval, ego-view detection, control, memory."""

import math

import numpy as np

from pipeline.scene import Scene
from stages import STAGES
from orion_eval.episode import EpisodeRun, Task
from orion_eval.memory import MemoryMaps
from orion_eval.scene import SceneContext
from orion_eval.user import SimulatedUser
from pipeline.nav.actions import FORWARD


def _run(tiny_scene, goal_index=0):
    ws, params = tiny_scene
    ctx = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    goal = [g for g in ctx.scene.goals.goals if ctx.scene.routes.for_goal(g.id)][goal_index]
    ep = ctx.scene.routes.for_goal(goal.id)[0]
    task = Task("tiny", "orion", "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m)
    user = SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0))
    return ctx, goal, EpisodeRun(ctx, task, user, 2000, 5)


def test_retrieve_map_finds_the_goal_class_and_goto_object_reaches_it(tiny_scene):
    ctx, goal, run = _run(tiny_scene)
    n_goals = len([g for g in ctx.scene.goals.goals if ctx.scene.routes.for_goal(g.id)])
    reached = []
    for k in range(n_goals):
        ctx, goal, run = _run(tiny_scene, k)
        m = run.modules
        hits = m.retrieve_map(goal.name, "vlmap")
        assert hits and all(len(t) == 3 for t in hits)
        dists = [d for _, d, _ in hits]
        assert dists == sorted(dists) and all(-math.pi <= a <= math.pi for _, _, a in hits)
        # one candidate lies on the goal's footprint (oracle features: the class is right)
        fp = ctx.footprint_mask(goal.object_keys).reshape(-1)
        on_goal = [i for i, _, _ in hits if fp[m.objects[i].cells].any()]
        assert on_goal, goal.name
        assert m.goto_object(on_goal[0])
        assert run.body.steps == len(run.body.actions) > 0
        reached.append(run.user.judge(run.body.pose)["success"])
    # The candidate's approach is planned on the map (its cells' centre in sight), success on the goal's mass
    # centre: a low object approached from its far side can hide it (a bathtub here; ~3 % of demo episodes).
    assert sum(reached) >= 0.75 * n_goals, reached


def test_detect_object_in_the_ego_view_and_double_check(tiny_scene):
    ctx, goal, run = _run(tiny_scene)
    m = run.modules
    oid = [i for i, _, _ in m.retrieve_map(goal.name, "vlmap")
           if ctx.footprint_mask(goal.object_keys).reshape(-1)[m.objects[i].cells].any()][0]
    m.goto_object(oid)
    dets = m.detect_object(goal.name)
    assert dets, "the goal in front of the agent is detected in the ray-cast ego view"
    d, a = m.relative(dets[0][0])
    assert d < 2.5 and abs(a) < math.radians(45)
    assert m.double_check(oid)
    view = ctx.view(run.body.pose)
    assert view.rgb.shape == (*ctx.params.eval.detect_size, 3) and view.hit.mean() > 0.8  # mesh holes: ~0.84 here
    assert np.isin(goal.instance_ids, view.instance).any()


def test_move_rotate_and_search(tiny_scene):
    ctx, goal, run = _run(tiny_scene)
    m = run.modules
    yaw0 = run.body.yaw
    m.rotate(math.radians(90))
    assert math.isclose(math.remainder(run.body.yaw - yaw0, 2 * math.pi), math.pi / 2, abs_tol=1e-9)
    oid = m.search_object(goal.name)
    assert oid is not None and run.body.steps >= 24  # spun first


def test_a_spin_is_remembered_where_it_was_made(tiny_scene):
    ctx, goal, run = _run(tiny_scene)
    m = run.modules
    first = m.look_around_for([goal.name, "bed"])
    spin = run.body.steps
    assert spin == 24  # 360 deg in 15 deg turns, every query detected in each of the 4 views
    again = m.look_around(goal.name)
    assert run.body.steps == spin and [t[0] for t in again] == [t[0] for t in first[goal.name]]  # no new steps
    m.look_around("chair")  # something not looked for here yet: a new spin
    assert run.body.steps == 2 * spin
    m.move(1.0)
    m.look_around(goal.name)  # another place: another spin
    assert run.body.steps == 2 * spin + 4 + spin
    hit = m.search_objects(["bicycle", goal.name])
    assert hit is not None and hit[0] == goal.name  # no bicycle anywhere: the goal, seen on the way


def _episode(ctx, goal):
    ep = ctx.scene.routes.for_goal(goal.id)[0]
    task = Task("tiny", "orion", "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m)
    return EpisodeRun(ctx, task, SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0)), 2000, 5)


def test_a_view_and_its_detections_do_not_depend_on_the_views_before_them(tiny_scene):
    """Two poses a few centimetres and degrees apart (one 5 cm place and turn step) each get their own view and
    detections, the same in a scene context that rendered the other first as in a fresh one."""
    ws, params = tiny_scene
    ctx, goal, run = _run(tiny_scene)
    x, y, yaw = run.body.pose
    near = (x + 0.012, y - 0.009, yaw + 0.05)
    assert ctx.pose_key(near) == ctx.pose_key((x, y, yaw))
    ctx.detect((x, y, yaw), goal.name)  # the other pose first
    fresh = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    assert np.array_equal(ctx.view(near).points, fresh.view(near).points)
    assert not np.array_equal(ctx.view(near).points, ctx.view((x, y, yaw)).points)
    seen = lambda c: [(d.center_xy.tolist(), d.cells.tolist(), d.score) for d in c.detect(near, goal.name)]  # noqa: E731
    assert seen(ctx) == seen(fresh)


def test_goto_object_targets_each_object_whatever_was_targeted_before(tiny_scene):
    """Two found objects whose cells share their first cell and their count are two targets: walking to one after
    the other (one scene context) ends where walking to it alone does."""
    ws, params = tiny_scene
    ctx, _, _ = _run(tiny_scene)
    goals = [g for g in ctx.scene.goals.goals if ctx.scene.routes.for_goal(g.id)]
    cells = [np.sort(np.flatnonzero(ctx.footprint_mask(g.object_keys).reshape(-1))) for g in goals[:2]]
    cells.sort(key=lambda c: c[0])
    n = min(len(c) for c in cells)
    first, second = cells[0][:n], np.concatenate([cells[0][:1], cells[1][: n - 1]])
    assert first.min() == second.min() and len(first) == len(second) and not np.array_equal(first, second)

    def walk(c, obj_cells):
        run = _episode(c, goals[0])
        rr, cc = np.divmod(obj_cells, c.grid.cols)
        center = np.median(c.grid.cell_to_world(np.stack([rr, cc], axis=1)), axis=0)
        assert run.modules.goto_object(run.modules.register(center, obj_cells, "detect"))
        return run.body.pose

    walk(ctx, first)
    fresh = SceneContext(Scene(ws, params, "tiny", STAGES, check=True))
    assert walk(ctx, second) == walk(fresh, second)


def test_memory_keeps_names_apart():
    from orion_eval.memory import lexical_feature

    enc = lambda texts: np.stack([np.eye(4)[0] for _ in texts])  # a class-level encoder: every chair alike
    mem = MemoryMaps(enc)
    mem.update(1, np.array([10, 11, 12]), "Bob's chair", "Alice's chair")
    mem.update(2, np.array([50, 51]), "Alice's chair", None)
    pos, neg = mem.retrieve("Alice's chair")
    assert pos == [2] and neg == [1]
    assert mem.retrieve("Bob's chair") == ([1], [])
    assert np.isclose(np.linalg.norm(lexical_feature("a b")), 1.0)


def test_the_agents_planners_recover_a_stranded_start_and_the_users_plans_as_the_routes_stage(tiny_scene):
    """The agents' planners get an agent stranded off the clearance band back into it (orion_eval.nav); the
    simulated user's procedural feedback is planned exactly as the routes stage plans, with no recovery, so what
    the user says does not change with the agents' navigation."""
    ctx, _, _ = _run(tiny_scene)
    assert ctx.planner.recover and ctx.view_planner.recover
    assert not ctx.user_planner.recover


def test_exploration_watches_the_view_ahead_on_the_way_to_a_frontier(tiny_scene):
    """The detector perceives on the fly while exploring: every WATCH_STEPS forward steps of a walk it looks at the
    view ahead, and a hit ends the walk there (no spin needed at the frontier)."""
    from orion_eval.modules import WATCH_STEPS

    ctx, goal, run = _run(tiny_scene)
    m = run.modules
    calls = []
    start = np.asarray(m.pose[:2])
    cells = ctx.planner.crop_grid.cell_to_world(np.argwhere(ctx.planner.planner.plan_mask))
    far = cells[int(np.argmax(np.hypot(*(cells - start).T)))]  # the navigable place farthest from the start
    assert m.goto_point(far, watch=lambda: calls.append(run.body.steps) or len(calls) == 2)
    forwards = [a for a in run.body.actions if a == FORWARD]
    assert len(calls) == 2 and len(forwards) == 2 * WATCH_STEPS  # stopped at the second look, short of the point
    assert float(np.hypot(*(np.asarray(m.pose[:2]) - far))) > 1.0
    # search_objects uses it: besides its spins' four views each, it looks at the views ahead on its walks
    ctx2, goal2, run2 = _run(tiny_scene)
    m2 = run2.modules
    looks, spins = [], []
    detect, spin = m2.detect_object, m2.look_around_for
    m2.detect_object = lambda s: looks.append(s) or detect(s)
    m2.look_around_for = lambda strs: spins.append(run2.body.steps) or spin(strs)
    assert m2.search_objects(["bicycle"]) is None  # nothing of the kind anywhere: every frontier target is walked to
    assert len(looks) > 4 * len(set(spins))  # spins at distinct steps: each a new place


def test_the_world_tests_a_step_as_the_agents_planners_do(tiny_scene):
    """Every step from every lattice cell of the clearance band, at every heading: the world lets the agent take it
    exactly when the agents' planners judged it free. (The world once tested steps in full-grid coordinates, where a
    step measured 5.0000000001 cells got one sample more than in the planners' cropped grid; one such step let a
    route walk into a wall and an exploration retry it until the step budget.)"""
    from orion_eval.world import Body

    ctx, _, _ = _run(tiny_scene)
    planner, cg = ctx.planner.planner, ctx.planner.crop_grid
    starts = cg.cell_to_world(np.argwhere(planner.plan_mask))
    checked = 0
    for x, y in starts[:: max(1, len(starts) // 400)].tolist():
        for k in range(24):
            yaw = math.radians(15 * k)
            body = Body(x, y, yaw)
            moved = ctx.world.act(body, FORWARD)
            free = planner.step_free(np.array([x, y]), np.array([x + ctx.step_m * math.cos(yaw),
                                                                  y + ctx.step_m * math.sin(yaw)]))
            assert moved == free, (x, y, 15 * k)
            checked += 1
    assert checked >= 24 * 400


def test_a_blocked_walk_ends_at_the_wall(tiny_scene):
    """When the world differs from what the agent planned on (here a wall across its route), a walk to a place or an
    object ends at the first collision and reports the place out of reach, and a ``move`` ends at the wall: the
    agent does not walk the rest of its route's actions from the wrong place."""
    from orion_eval.world import World

    ctx, _, run = _run(tiny_scene)
    m = run.modules
    start = np.asarray(m.pose[:2])
    cells = ctx.planner.crop_grid.cell_to_world(np.argwhere(ctx.planner.planner.plan_mask))
    far = cells[int(np.argmax(np.hypot(*(cells - start).T)))]
    rc = ctx.grid.world_to_cell(np.asarray(far, np.float64))
    route = ctx.planner.route(m.pose, ctx.planner.point_mask(far), key=("pt", int(rc[0]), int(rc[1])))
    # a wall across the route's path halfway, where the planners never saw one
    path = route.path.polyline_xy
    mid = path[len(path) // 2]
    nav = ctx.world.nav.copy()
    r, c = ctx.planner.crop_grid.world_to_cell(np.asarray(mid, np.float64))
    nav[max(r - 8, 0):r + 9, max(c - 8, 0):c + 9] = False
    ctx.world = World(nav, ctx.planner.crop_grid, step_m=ctx.step_m, turn_deg=ctx.turn_deg)
    assert not m.goto_point(far)
    assert run.body.collisions == 1 and run.body.steps < len(route.actions)
    steps = run.body.steps
    assert not ctx.world.act(run.body, FORWARD)  # it stands at the wall, facing it
    m.move(100.0)
    assert run.body.steps == steps + 2 and run.body.collisions == 3  # one more collision in move, then it stops


def test_an_exploration_with_hints_goes_first_to_the_frontier_nearest_them(tiny_scene):
    """A landmark found (or a route's end) says where the goal is: the frontier nearest it in whole metres comes first,
    the agent's distance breaks ties; without hints, the nearest frontier."""
    from scipy import ndimage

    ctx, _, run = _run(tiny_scene)
    m = run.modules
    m.look_around("chair")
    plain = m.frontier()
    assert plain is not None
    ex = m._explored_mask()
    rr, cc = np.nonzero(ctx.planner.planner.plan_mask & ~ex & ndimage.binary_dilation(ex))
    xy = ctx.planner.crop_grid.cell_to_world(np.stack([rr, cc], axis=1))
    xy = xy[np.hypot(xy[:, 0] - m.pose[0], xy[:, 1] - m.pose[1]) >= 1.0]
    far = xy[np.argmax(np.hypot(*(xy - plain).T))]  # the frontier farthest from the nearest one
    assert np.hypot(*(plain - far)) > 1.0
    hinted = m.frontier(near=far[None])
    assert np.hypot(*(hinted - far)) < 0.5  # the frontier at the hint, not the nearest one
    assert np.array_equal(m.frontier(near=None), plain)


def _house_runs(tiny_house, cross: bool):
    """ORION episodes of the tiny house, one per goal with an episode starting on another floor (``cross``) or on its
    own floor: ``(ctx, goal, EpisodeRun)``."""
    ws, params = tiny_house
    ctx = SceneContext(Scene(ws, params, "house", STAGES, check=True))
    for goal in ctx.scene.goals.goals:
        for ep in ctx.scene.routes.for_goal(goal.id):
            if (ep.start_floor != goal.floor) == cross:
                task = Task("house", "orion", "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m, ep.start_floor)
                user = SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0))
                yield ctx, goal, EpisodeRun(ctx, task, user, 2000, 5)
                break


def _house_run(tiny_house, cross: bool):
    found = next(_house_runs(tiny_house, cross), None)
    assert found is not None, "the tiny house has no such episode"
    return found


def test_take_stairs_walks_to_the_stair_and_climbs_it_with_forward_steps(tiny_house):
    ctx, goal, run = _house_run(tiny_house, cross=True)
    m = run.modules
    start = m.floor
    assert ctx.is_building and len(ctx.world.stairs) >= 1 and start != goal.floor
    assert m.take_stairs(goal.floor)
    assert m.floor == goal.floor and run.body.collisions == 0
    assert run.body.floors[0] == start and run.body.floors[-1] == goal.floor
    assert any(e[1] == "stairs" for e in run.events)
    # climbing: the last actions are forward steps along the stair
    assert run.body.actions[-ctx.world.stairs[0].steps:] == [FORWARD] * ctx.world.stairs[0].steps
    assert m.take_stairs(goal.floor) and m.floor == goal.floor  # already there: nothing to do


def test_a_map_candidate_on_another_floor_is_reached_over_the_stairs_after_those_on_the_agents_floor(tiny_house):
    """Every floor's map answers ``retrieve_map``; the candidates of the agent's floor rank first (the controller),
    and ``goto_object`` on a candidate of the other floor climbs there and ends in its goal region."""
    from orion_eval.agents.controller import ModularAgent, SearchState

    ctx, _, run = _house_run(tiny_house, cross=True)
    m, here = run.modules, run.modules.floor
    from pipeline.nav.verify import point_polygon_distance

    for key, obj in sorted(ctx.scene.goals.objects.items()):  # an object of the other floor the map finds
        if obj.floor == here:
            continue
        hits = [i for i, _, _ in m.retrieve_map(obj.cls, "vlmap")]
        fp = ctx.footprint_mask((key,)).reshape(-1)
        on_it = [i for i in hits if m.objects[i].floor == obj.floor and fp[m.objects[i].cells].any()]
        if on_it and any(m.objects[i].floor == here for i in hits):
            break
    else:
        raise AssertionError("the map finds no object of the other floor beside candidates on the agent's")
    ranked = ModularAgent(ctx.params).ranked(m, SearchState(name=obj.cls), hits)
    own = [i for i in ranked if m.objects[i].floor == here]
    assert own and ranked[:len(own)] == own  # the agent's floor first
    assert m.goto_object(on_it[0]) and m.floor == obj.floor and run.body.collisions == 0
    assert point_polygon_distance(m.pose[:2], np.asarray(obj.footprint)) <= ctx.success_m


def test_an_exploration_with_no_frontier_left_on_its_floor_goes_on_on_the_next(tiny_house):
    ctx, goal, run = _house_run(tiny_house, cross=False)
    m = run.modules
    here = m.floor
    assert m.floor_to_explore() == 1 - here  # the other floor: never looked around on
    m._explored_mask()[:] = True  # this floor explored to the end
    assert m.frontier() is None and m.can_explore()
    m.search_objects(["a purple elephant"])
    assert (1 - here) in run.body.floors and any(e[1] == "stairs" for e in run.events)
    assert (1 - here) in m._explored  # looked around on the other floor


def test_an_agent_stopped_on_a_stair_walks_off_it_before_it_plans(tiny_house):
    ctx, goal, run = _house_run(tiny_house, cross=True)
    m = run.modules
    way = ctx.world.stairs[0]
    lower = way.link.lower
    if m.floor == lower:
        assert m.take_stairs(way.link.upper)
    assert m.take_stairs(lower) and tuple(m.pose[:2]) == way.link.foot_xy  # down: arrived at the foot
    m.rotate(way.up_heading - m.pose[2])  # turned back: the stair is stepped onto from where a climb arrives
    run.act(FORWARD), run.act(FORWARD)
    assert run.body.stair is not None and m.floor == lower  # two steps up the stair
    m.leave_stair()
    assert run.body.stair is None and m.floor == way.link.upper


def test_a_task_that_does_not_name_its_floor_starts_on_its_episodes(tiny_house):
    """The workbench's Play builds its task from the episode without a floor: the run starts on the floor
    routes.zarr records for the episode."""
    ctx, goal, run = _house_run(tiny_house, cross=True)
    ep = next(e for e in ctx.scene.routes.episodes if e.id == run.task.episode_id)
    task = Task("house", "orion", "yesno", 0, goal.id, ep.id, ep.start, ep.geodesic_m)  # no start_floor
    bare = EpisodeRun(ctx, task, SimulatedUser(ctx, goal, "yesno", np.random.default_rng(0)), 2000, 5)
    assert bare.body.floor == ep.start_floor != goal.floor and bare.start_floor == ep.start_floor


def test_an_exploration_restarted_starts_over_from_where_the_agent_stands(tiny_scene):
    """restart_exploration forgets the places covered, not what each spin saw: a spin remembered where the agent stands
    costs no steps and covers its place again, so the frontiers are those around it, the earlier places' included."""
    ctx, goal, run = _run(tiny_scene)
    m = run.modules
    m.look_around("bicycle")
    first = m._explored_mask().copy()
    target = m.frontier()
    assert target is not None and m.goto_point(target)
    m.look_around("bicycle")
    both = m._explored_mask().copy()
    assert (both & ~first).any()  # the second spin covered more
    steps = run.body.steps
    m.restart_exploration()
    m.look_around("bicycle")  # remembered here: no steps, and only this place is covered now
    assert run.body.steps == steps
    here = m._explored_mask()
    assert here.any() and (first & ~here).any() and not (here & ~both).any()
    assert m.frontier() is not None



def test_the_sides_of_an_object_are_navigable_points_round_it_away_from_the_agent(tiny_scene):
    """sides_of gives the points a landmark's other sides are looked at from: navigable, SIDE_M from its centre, none
    on the side the agent comes from, a quarter turn apart going round it."""
    from orion_eval.modules import SIDE_M
    from orion_eval.nav import points_round

    ctx, goal, run = _run(tiny_scene)
    m = run.modules
    mark = np.asarray(goal.mass_center[:2], np.float64)
    here = np.asarray(m.pose[:2], np.float64)
    sides = m.sides_of(mark, here)
    assert 1 <= len(sides) <= 3
    g, nav = ctx.grid, m.here.navigable
    start = math.atan2(*(here - mark)[::-1])
    for p in sides:
        rc = g.world_to_cell(p)
        assert nav[rc[0], rc[1]] and math.isclose(float(np.hypot(*(p - mark))), SIDE_M)
        off = abs((math.atan2(*(p - mark)[::-1]) - start + math.pi) % (2 * math.pi) - math.pi)
        assert off >= math.pi / 4 - 1e-9  # never on the agent's own side
    # on a floor with nothing navigable there is no side to look from; an open floor has all three
    assert points_round(np.zeros_like(nav), g, mark, here, SIDE_M) == []
    open_floor = points_round(np.ones_like(nav), g, mark, here, SIDE_M)
    bearings = [math.degrees(math.atan2(*(p - mark)[::-1]) - start) % 360 for p in open_floor]
    assert np.allclose(bearings, [90, 180, 270])
