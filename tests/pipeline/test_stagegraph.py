"""The stage graph: the order and levels of the registered stages (staleness is exercised through the runner
in test_runner.py)."""

from pipeline.stagegraph import stage_levels, stage_order
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
