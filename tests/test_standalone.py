"""zipon stands on its own: what a user clones, copied into an empty folder with nothing beside it, builds a
simulated scene with every stage and evaluates it; no tracked file points outside the repository."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
NEEDLES = ("../" + "shared", "shared/" + "data")  # the folder beside a developer's checkout that no clone has
SMALL = """\
scenes:
  alone: {source: simulate}
simulate: {frames: 120, width: 160, height: 120, rooms_min: 3, rooms_max: 3}
reconstruct: {voxel_size_m: 0.05}
encoders:
  simulated_lseg: {out_size: [30, 40]}
  simulated_cf: {out_size: [30, 40]}
goals: {max_goals: 4}
routes: {episodes_per_goal: 1}
eval: {workers: 1}
"""


def repository_files() -> list[str]:
    """What a clone holds: the tracked files, plus the files not yet committed that git does not ignore (so the
    test checks the change under test, not only the last commit)."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                         capture_output=True, check=True).stdout.decode()
    return sorted({f for f in out.split("\0") if f and (REPO / f).is_file()})


@pytest.fixture(scope="module")
def alone(tmp_path_factory) -> Path:
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout: nothing to tell a clone's files by")
    root = tmp_path_factory.mktemp("empty") / "zipon"
    for name in repository_files():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, root / name)
    return root


def zipon(root: Path, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """``zipon ARGS`` run from the copy with the copy's own code first on the import path."""
    env = {**os.environ, "PYTHONPATH": str(root), "HF_HUB_OFFLINE": "1", "DVC_NO_ANALYTICS": "1",
           "ZIPON_CACHE": str(root.parent / "cache")}
    env.pop("ZIPON_DATA", None), env.pop("ZIPON_MANIFESTS", None)
    return subprocess.run([sys.executable, "-m", "zipon.cli", *args], cwd=root, env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_no_tracked_file_points_outside_the_repository():
    hits = [f"{name}:{i}" for name in repository_files()
            if not name.endswith((".png", ".jpg", ".npy", ".zarr"))
            for i, line in enumerate((REPO / name).read_text(errors="replace").splitlines(), 1)
            if any(needle in line for needle in NEEDLES)]
    assert hits == []


def test_the_copy_imports_its_own_code_with_nothing_beside_it(alone):
    assert [p.name for p in alone.parent.iterdir()] == ["zipon"]
    env = {**os.environ, "PYTHONPATH": str(alone)}
    found = subprocess.run([sys.executable, "-c", "import pipeline, stages, orion_eval, zipon; "
                            "print(pipeline.__file__, stages.__file__, orion_eval.__file__, zipon.__file__)"],
                           cwd=alone, env=env, capture_output=True, text=True, check=True).stdout.split()
    assert all(Path(f).is_relative_to(alone) for f in found), found


def test_a_copy_with_nothing_beside_it_builds_and_evaluates_a_scene(alone):
    (alone / "small.yaml").write_text(SMALL)
    run = zipon(alone, "-q", "-p", "small.yaml", "run")
    assert run.returncode == 0, run.stderr[-3000:]
    manifests = sorted(p.stem for p in (alone / "manifests" / "alone").glob("*.json"))
    assert manifests == ["cfmap", "goals", "ingest", "reconstruct", "routes", "simulate", "vlmap"]
    vlmap = json.loads((alone / "manifests" / "alone" / "vlmap.json").read_text())
    assert vlmap["params"]["encoders.simulated_lseg"]["embeddings"] is None  # the shipped ones, in the copy
    assert vlmap["summary"]["encoder"] == "simulated_lseg" and vlmap["summary"]["frames_fused"] == 120

    ev = zipon(alone, "-q", "-p", "small.yaml", "eval", "--out", "ev", "-m", "orion", "-f", "none", "--seeds", "1")
    assert ev.returncode == 0, ev.stderr[-3000:]
    results = json.loads((alone / "ev" / "results.json").read_text())
    assert list(results["by_scene"]) == ["alone"] and results["overall"]["orion"]["none"]["episodes"] >= 1
    assert {e["scene"] for e in results["episodes"]} == {"alone"}
    assert (alone / "ev" / "report.html").is_file()
