import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("DVC_NO_ANALYTICS", "1")

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
TUM_RPY = SHARED / "data" / "real" / "tum_fr1_rpy_head30"


@pytest.fixture
def workspace(tmp_path):
    """A fresh workspace (params.yaml, data/, manifests/) in a temp dir."""
    from pipeline.paths import Workspace

    (tmp_path / "params.yaml").write_text("scenes:\n  s0: {source: simulate}\n  s1: {source: simulate}\n")
    return Workspace.resolve(tmp_path / "params.yaml")
