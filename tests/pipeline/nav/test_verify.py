import numpy as np

from pipeline.nav.actions import FORWARD, LEFT, STOP
from pipeline.routes.episodes import GoalTarget, make_episodes
from pipeline.nav.verify import replay
from tests.fixtures.goal_scenes import corridor_grid, gt_navigable, house_grid, house_scene

SQUARE = np.array([[5.4, 4.7], [5.6, 4.7], [5.6, 4.9], [5.4, 4.9]])


def test_replay_detects_collision_and_distance():
    nav, grid = corridor_grid()
    into_wall = np.array([LEFT] * 6 + [FORWARD] * 4 + [STOP])  # north from y = 0.5: wall at y = 1
    res = replay(into_wall, (0.5, 0.5, 0.0), nav, grid, [SQUARE])
    assert res.collisions == 2 and res.first_collision == 8 and not res.success
    ok = replay(np.array([FORWARD] * 20 + [STOP]), (0.5, 0.5, 0.0), nav, grid, [SQUARE])
    assert ok.collisions == 0 and np.isclose(ok.final_xyyaw[0], 5.5) and not ok.success  # 4.2 m short
    assert np.isclose(ok.distance_to_goal_m, 4.7 - 0.5)


def test_episodes_on_the_house_all_verified_and_seeded():
    gt, grid = house_scene(), house_grid()
    nav = gt_navigable(gt, grid)
    objs = {o.id: o for o in gt.objects}
    targets = []
    for oid in (6, 8, 11):
        m = np.zeros_like(nav)
        from pipeline.scene_gt import _paint_box

        _paint_box(m, grid, objs[oid].parts[0])
        b = objs[oid].bbox
        poly = np.array([[b.min[0], b.min[1]], [b.max[0], b.min[1]], [b.max[0], b.max[1]], [b.min[0], b.max[1]]])
        targets.append(GoalTarget(str(oid), m, [poly], poly.mean(0)))
    a = make_episodes(nav, grid, targets, episodes_per_goal=4, min_geodesic_m=3.0, seed=1)
    b = make_episodes(nav, grid, targets, episodes_per_goal=4, min_geodesic_m=3.0, seed=1)
    assert len(a.episodes) == a.generated == 12 and not a.rejected and not a.unreachable
    assert [e.start for e in a.episodes] == [e.start for e in b.episodes]
    assert all(e.geodesic_m >= 3.0 and e.final_distance_m <= 1.5 for e in a.episodes)
    boxed = GoalTarget("x", np.zeros_like(nav), [np.zeros((3, 2))], np.zeros(2))
    assert make_episodes(nav, grid, [boxed], episodes_per_goal=1, min_geodesic_m=1.0, seed=0).unreachable[0]["goal"] == "x"
