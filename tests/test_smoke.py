"""Start to finish on a tiny simulated scene through the CLI: run, status, verify, rerun, pictures, query,
and the on-disk formats checked against the trees documented in the modules."""

import ast
import json
import re
from pathlib import Path

import zarr

from zipon.cli import main
from pipeline.engine.manifest import Manifest
from stages import STAGES

REPO = Path(__file__).resolve().parents[1]
FORMAT_DOCS = {
    "frames": "pipeline/frames.py",
    "recon": "pipeline/recon/store.py",
    "vlmap": "pipeline/maps/store.py",
    "cfmap": "pipeline/maps/store.py",
    "goals": "pipeline/goals/store.py",
    "routes": "pipeline/routes/store.py",
}
GLYPH = re.compile(r"^(?P<indent>(?:│   |    )*)(?:├──|└──) (?P<name>[A-Za-z_]\w*/?)(?P<rest>.*)$")


def documented_tree(module_file: str) -> tuple[set[str], set[str]]:
    """(all node paths, optional node paths) from the format tree in a module docstring."""
    doc = ast.get_docstring(ast.parse((REPO / module_file).read_text()))
    nodes, optional, stack = set(), set(), []
    for line in doc.splitlines():
        m = GLYPH.match(line.strip("\n").lstrip(" ") if not line.startswith("    ") else line[4:])
        if not m:
            continue
        depth = len(m["indent"]) // 4
        stack = stack[:depth] + [m["name"].rstrip("/")]
        path = "/".join(stack)
        nodes.add(path)
        if re.search(r"optional|only|when ", m["rest"]):
            optional.add(path)
    return nodes, optional


def store_tree(path: Path) -> set[str]:
    group = zarr.open_group(str(path), mode="r")
    return {name for name, _ in group.members(max_depth=None)}


def cli(ws, *args) -> int:
    return main(["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir),
                 "--manifests-dir", str(ws.manifests_dir), *args])


def test_every_stage_ran_and_recorded_its_lineage(built_scene):
    ws, params = built_scene
    for stage in STAGES:
        man = Manifest.read(ws.manifest("tiny", stage))
        assert man is not None, f"no manifest for {stage}"
        for name in STAGES[stage].outputs:
            assert ws.artifact(name, "tiny").exists()
            assert man.outputs[name].digest.startswith("blake3:")
    recon = Manifest.read(ws.manifest("tiny", "reconstruct")).outputs["recon"].digest
    for stage in ("vlmap", "cfmap", "goals", "routes"):
        assert Manifest.read(ws.manifest("tiny", stage)).inputs["recon"] == recon


def test_formats_match_their_documented_trees(built_scene):
    ws, _ = built_scene
    for artifact, module in FORMAT_DOCS.items():
        nodes, optional = documented_tree(module)
        actual = store_tree(ws.artifact(artifact, "tiny"))
        assert actual <= nodes, f"{artifact}: undocumented {sorted(actual - nodes)} (document them in {module})"
        expected = {n for n in nodes if artifact == "vlmap" and not n.startswith("voxels")
                    or artifact != "vlmap"} - optional
        assert expected <= actual, f"{artifact}: documented but missing {sorted(expected - actual)}"


def test_status_verify_and_rerun_are_clean(built_scene, capsys):
    ws, _ = built_scene
    before = {s: Manifest.read(ws.manifest("tiny", s)).outputs for s in STAGES}
    assert cli(ws, "run") == 0
    assert capsys.readouterr().out.count("skipped") == len(STAGES)
    assert cli(ws, "status") == 0
    assert "0 stale stage(s)" in capsys.readouterr().out
    assert cli(ws, "verify") == 0
    assert f"{sum(len(s.outputs) for s in STAGES.values())} artifact(s) match" in capsys.readouterr().out
    assert {s: Manifest.read(ws.manifest("tiny", s)).outputs for s in STAGES} == before


def test_pictures_and_query(built_scene, tmp_path, capsys):
    ws, _ = built_scene
    for what in ("frames", "plan", "obstacles", "navigable", "color", "height", "goals", "routes"):
        out = tmp_path / f"{what}.png"
        assert cli(ws, "render", "tiny", "--what", what, "-o", str(out)) == 0, what
        assert out.stat().st_size > 1000
    capsys.readouterr()
    png = tmp_path / "q.png"
    assert cli(ws, "query", "tiny", "chair", "--pose", "0,0,0", "--json", "--png", str(png)) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["text"] == "chair" and result["candidates"], result
    assert png.stat().st_size > 1000


def test_bad_scene_and_stage_are_clear_errors(built_scene, capsys):
    ws, _ = built_scene
    assert cli(ws, "stage", "reconstrukt", "--scene", "tiny") == 1
    assert "unknown stage 'reconstrukt'" in capsys.readouterr().err


def test_recon_eval_scores_the_built_grids_against_the_ground_truth(built_scene, capsys):
    ws, _ = built_scene
    frames, recon = ws.artifact("frames", "tiny"), ws.artifact("recon", "tiny")
    capsys.readouterr()
    assert cli(ws, "recon-eval", str(frames), "--recon", str(recon)) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["recon"] == str(recon) and figures["floor_error_m"] <= 0.02
    assert 0.5 < figures["iou_occupied"] <= figures["iou_occupied_seen"] <= 1.0
