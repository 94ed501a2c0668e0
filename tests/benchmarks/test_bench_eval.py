"""benchmarks/bench_eval.py's build step: which of a workspace's stages lag their code, params or inputs, so that
the findings check reruns them and the timing names them instead of reading figures off stale artifacts."""

from __future__ import annotations

import pytest


@pytest.fixture
def bench(load_script):
    return load_script("bench_eval")


def test_a_built_scene_has_no_stale_stage_and_a_params_change_names_the_stage_and_the_key(bench, built_scene):
    from pipeline.stagegraph import plan
    from stages import STAGES

    ws, params = built_scene
    pairs = plan(STAGES, params, list(params.scenes))
    assert {stage for _, stage in pairs} >= {"ingest", "reconstruct", "vlmap", "goals", "routes"}
    assert bench.stale_stages(ws, params, pairs) == {}

    changed = params.model_copy(update={"goals": params.goals.model_copy(update={"max_goals": 9})})
    stale = bench.stale_stages(ws, changed, pairs)
    assert "tiny/goals" in stale and "goals.max_goals 8 -> 9" in stale["tiny/goals"]
    assert not any(k in stale for k in ("tiny/ingest", "tiny/reconstruct", "tiny/vlmap"))
