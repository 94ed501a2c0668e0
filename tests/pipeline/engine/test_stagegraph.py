"""The stage graph: the order and levels of the registered stages, and which stages are stale (staleness itself is
exercised through the runner in test_runner.py)."""

from pipeline.engine.stagegraph import plan, stage_levels, stage_order, stale_stages
from stages import STAGES


def test_stage_levels_put_the_long_chains_first():
    """Each stage's level (its dask priority) is the longest path to a stage nothing reads: the raw chain
    (simulate, ingest, reconstruct) before goals, goals before the stages whose work spreads over the workers."""
    assert stage_levels(STAGES) == {"simulate": 4, "ingest": 3, "reconstruct": 2, "goals": 1, "routes": 0,
                                    "vlmap": 0, "cfmap": 0}


def test_stage_order_puts_every_producer_before_its_readers():
    order = stage_order(STAGES)
    assert sorted(order) == sorted(STAGES)
    for name in order:
        for artifact in STAGES[name].inputs:
            producers = [s for s in STAGES if artifact in STAGES[s].outputs or (artifact == "source" and s == "simulate")]
            assert all(order.index(p) < order.index(name) for p in producers), (name, artifact)


def test_a_built_scene_has_no_stale_stage_and_a_params_change_names_the_stage_and_the_key(built_scene):
    """What the findings check reruns and the evaluator's results name (``run.stale``): the stages whose outputs lag
    their code, params or inputs, with why."""
    ws, params = built_scene
    pairs = plan(STAGES, params, list(params.scenes))
    assert {stage for _, stage in pairs} >= {"ingest", "reconstruct", "vlmap", "goals", "routes"}
    assert stale_stages(ws, params, STAGES, pairs) == {}

    changed = params.model_copy(update={"goals": params.goals.model_copy(update={"max_goals": 9})})
    stale = stale_stages(ws, changed, STAGES, pairs)
    assert "tiny/goals" in stale and "goals.max_goals 8 -> 9" in stale["tiny/goals"]
    assert not any(k in stale for k in ("tiny/ingest", "tiny/reconstruct", "tiny/vlmap"))
