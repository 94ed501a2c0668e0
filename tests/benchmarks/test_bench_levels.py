"""benchmarks/bench_levels.py on a project holding a cfmap of many voxel blocks: one line per call, the background's
cost apart, the features held from the second call when they fit."""

from __future__ import annotations

import json

from pipeline.paths import Workspace
from tests.fixtures.level_maps import write_tiled_cfmap


def test_bench_levels_times_each_call_and_holds_from_the_second(tmp_path, load_script, monkeypatch, capsys):
    (tmp_path / "params.yaml").write_text(json.dumps({"scenes": {"t": {"source": "simulate"}},
                                                       "encoders": {"oracle": {"dim": 48}}}))
    cfmap = Workspace.resolve(tmp_path / "params.yaml").artifact("cfmap", "t")
    cfmap.parent.mkdir(parents=True)
    write_tiled_cfmap(cfmap)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    bench = load_script("bench_levels")
    monkeypatch.setattr("sys.argv", ["bench_levels.py", "--project", str(tmp_path), "--scene", "t", "--texts",
                                     "chair", "bed", "--hold-mb", "64"])
    bench.main()
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    head, calls = lines[0], lines[1:]
    assert head["what"] == "map" and head["voxels"] > 30_000 and head["blocks"] == -(-head["voxels"] // 4096)
    assert [(c["text"], c["background"], c["call"], c["held"]) for c in calls] == [
        ("chair", 4, 1, False), ("chair", 4, 2, True), ("chair", 0, 3, True),
        ("bed", 4, 4, True), ("bed", 4, 5, True), ("bed", 0, 6, True)]
    assert all(c["seconds"] > 0 and c["peak_rss_mb"] > 0 for c in calls)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # nothing written there
