"""The Artifacts view and its lineage check."""

import json
import shutil

import pytest

from orion_eval.artifacts import Artifacts
from pipeline.errors import LineageError, MissingInputError
from pipeline.paths import Workspace


def test_lineage_ok_and_lazy_views(tiny_scene):
    ws, params = tiny_scene
    arts = Artifacts(ws, params, "tiny")
    shared = arts.check_lineage()
    assert set(shared) == {"recon", "goals"}
    assert arts.grid == arts.recon.grid == arts.goals.grid == arts.routes.grid
    assert arts.gt is not None and len(arts.routes.episodes) > 0
    assert 0.7 < arts.camera_height_m < 1.0  # the simulator's 0.88 m camera


def test_mismatched_reconstruction_is_a_lineage_error(tiny_scene, tmp_path):
    ws, params = tiny_scene
    manifests = tmp_path / "manifests"
    shutil.copytree(ws.manifests_dir, manifests)
    path = manifests / "tiny" / "goals.json"
    doc = json.loads(path.read_text())
    doc["inputs"]["recon"] = "blake2b:" + "0" * 32  # goals built from another reconstruction
    path.write_text(json.dumps(doc))
    other = Workspace(ws.root, ws.data_dir, manifests)
    with pytest.raises(LineageError, match=r"scene tiny: goals was built from recon blake2b:0{32}, but .*reconstruct\.json"):
        Artifacts(other, params, "tiny")
    (manifests / "tiny" / "routes.json").unlink()
    with pytest.raises(MissingInputError, match="no manifest of stage routes"):
        Artifacts(other, params, "tiny", check=False).check_lineage(("routes",))
