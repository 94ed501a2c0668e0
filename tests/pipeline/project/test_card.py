import json
import shutil

import pytest

from pipeline import __version__, plugins
from pipeline.paramsfile import parse_params
from pipeline.paths import Workspace
from pipeline.project.card import SOURCE_LICENCES, build_card, card_markdown
from stages import STAGES
from tests.pipeline.project.conftest import artifact_digests, git
from zipon.cli import main


@pytest.mark.slow
def test_the_card_of_a_version_states_what_it_holds_and_is_committed_with_it(dataset_versions):
    root = dataset_versions.root
    assert {"DATASET.md", "dataset.json"} <= set(git(root, "ls-files").split())
    card = json.loads((root / "dataset.json").read_text())
    scene = card["scenes"]["sim_00"]
    assert (scene["source"], scene["format"], scene["frames"], scene["floors"], scene["rooms"]) == (
        "simulate", "simulate", 6, 1, 2)
    assert scene["goals"] == len(scene["goal_list"]) == 2  # v2: goals.max_goals 2
    assert set(scene["feedback"]) == {"corrective", "descriptive", "landmark", "procedural"}
    assert scene["feedback"]["descriptive"] == 2 and all(g["name"] and g["digest"] for g in scene["goal_list"])
    assert scene["licence"]["licence"].startswith("no third-party data")
    assert card["zipon_version"] == __version__ and card["complete"] and card["not_built"] == []
    flat = {f"{s}/{a}": d for s, arts in card["artifacts"].items() for a, d in arts.items()}
    assert flat == artifact_digests(root) == dataset_versions.digests["v2"]
    for stage, versions in card["stages"].items():
        identity = json.loads((root / ".zipon" / "code" / f"{stage}.json").read_text())
        assert versions == {"code_digests": [identity["code_digest"]], "zipon_versions": [__version__]}
    assert {(e["map"], e["encoder"]) for e in card["encoders"]} == {("vlmap", "simulated_lseg"),
                                                                     ("cfmap", "simulated_cf")}
    assert all(e["kind"].startswith("simulated perception model") for e in card["encoders"])
    assert card["params_digest"].startswith("blake2b:") and "dvc pull" in card["restore"]
    text = (root / "DATASET.md").read_text()
    assert text == card_markdown(card)
    for fact in ("| sim_00 | `simulate` | simulate | 6 | 1 | 2 | 2 |", "`simulated_lseg`, simulated perception",
                 card["basis_digest"], "## Cite", "dvc pull", dataset_versions.digests["v2"]["sim_00/goals"]):
        assert fact in text
    git(root, "show", "v1:dataset.json")  # every version has its own card
    assert json.loads(git(root, "show", "v1:dataset.json"))["scenes"]["sim_00"]["goals"] == 3


@pytest.mark.slow
def test_status_check_fails_while_the_card_is_stale(dataset_versions, tmp_path, capsys):
    root = tmp_path / "ds"
    shutil.copytree(dataset_versions.root, root, symlinks=True)
    params = str(root / "params.yaml")
    assert main(["-p", params, "status", "--check"]) == 0 and main(["-p", params, "card", "--check"]) == 0
    card = json.loads((root / "dataset.json").read_text())
    (root / "dataset.json").write_text(json.dumps({**card, "basis_digest": "blake2b:older"}))
    capsys.readouterr()
    assert main(["-p", params, "status", "--check"]) == 1
    said = " ".join(capsys.readouterr().err.split())
    assert "dataset card stale: dataset.json states another version" in said and "zipon card" in said
    assert main(["-p", params, "card", "--check"]) == 1
    assert main(["-p", params, "card"]) == 0
    assert (root / "dataset.json").read_text() == (dataset_versions.root / "dataset.json").read_text()
    (root / "DATASET.md").unlink()
    assert main(["-p", params, "status", "--check"]) == 1
    assert "DATASET.md missing" in capsys.readouterr().err
    assert main(["-p", params, "card"]) == 0 and main(["-p", params, "status", "--check"]) == 0
    identity = root / ".zipon" / "code" / "goals.json"
    identity.write_text(identity.read_text().replace('"code_digest": "blake2b:', '"code_digest": "blake2b:0ld'))
    capsys.readouterr()
    assert main(["-p", params, "status"]) == 0
    assert "for DVC: .zipon/code/goals.json: stage goals's code identity is out of date" in " ".join(
        capsys.readouterr().err.split())
    (root / "dataset.json").write_text("[1, 2]")
    assert main(["-p", params, "card", "--check"]) == 1
    assert "not a zipon dataset card" in capsys.readouterr().err


def test_recorded_sources_name_the_licence_their_reader_knows(tmp_path):
    """Only formats zipon reads carry a licence, and a format with none known says so; nothing needs building."""
    assert set(SOURCE_LICENCES) <= set(plugins.BUILT_IN_READERS)
    scenes = {"desk": ("raw/desk", "tum"), "chess": ("raw/chess", "7scenes"), "room0": ("raw/room0", "replica"),
              "scan": ("raw/scene0000_00", "scannet"), "robot": ("raw/robot.mcap", "mcap")}
    params = parse_params({"scenes": {n: {"source": s, "format": f} for n, (s, f) in scenes.items()}})
    card = build_card(Workspace.resolve(tmp_path / "params.yaml"), params, STAGES)
    licences = {n: (s["licence"] or {}).get("licence", "") for n, s in card["scenes"].items()}
    assert licences["desk"] == "CC BY 4.0" and "non-commercial" in licences["chess"]
    assert "Replica" in card["scenes"]["room0"]["licence"]["dataset"] and "ScanNet" in card["scenes"]["scan"][
        "licence"]["dataset"]
    assert licences["robot"] == "" and not card["complete"] and "desk/ingest" in card["not_built"]
    text = card_markdown(card)
    assert "- robot: format mcap: licence not known to zipon; state it here" in text
    assert "- desk: goals not built" in text and "| desk | `raw/desk` | tum | unknown |" in text
