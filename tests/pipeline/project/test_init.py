import configparser
import subprocess

import yaml

from pipeline.paramsfile import load_params
from stages import STAGES
from zipon.cli import main


def test_init_makes_a_git_and_dvc_project_that_zipon_can_run(tmp_path, capsys):
    root = tmp_path / "ds"
    assert main(["init", str(root)]) == 0
    shown = capsys.readouterr().out
    assert "initialised git" in shown and "initialised dvc" in shown and "Initialized DVC" not in shown
    assert {p.name for p in root.iterdir()} >= {".git", ".dvc", ".gitignore", "README.md", "params.yaml", "dvc.yaml",
                                                ".zipon"}
    config = configparser.ConfigParser()
    config.read(root / ".dvc" / "config")
    assert config["core"]["analytics"].lower() == "false" and config["core"]["check_update"].lower() == "false"
    assert subprocess.run(["git", "-C", str(root), "rev-parse", "--git-dir"], capture_output=True).returncode == 0
    params = load_params(root / "params.yaml")
    assert list(params.scenes) == ["sim_00"] and params.scenes["sim_00"].simulated
    text = (root / "params.yaml").read_text()
    assert "#   desk: {source: raw/rgbd_dataset_freiburg1_desk, format: tum}" in text and "# frames recorded" in text
    assert "/data/" in (root / ".gitignore").read_text().splitlines()
    readme = (root / "README.md").read_text()
    assert all(step in readme for step in ("zipon run", "git tag v1", "zipon push", "zipon pull", "zipon verify"))
    deps = yaml.safe_load((root / "dvc.yaml").read_text())["stages"]["goals"]["do"]["deps"]
    assert ".zipon/code/goals.json" in deps and not [d for d in deps if d.endswith(".py")]
    assert {p.stem for p in (root / ".zipon" / "code").iterdir()} == set(STAGES)
    assert main(["-p", str(root / "params.yaml"), "dvc", "--check"]) == 0


def test_init_completes_a_zipon_project_and_keeps_what_it_has(tmp_path, capsys):
    root = tmp_path / "ds"
    assert main(["init", str(root)]) == 0
    (root / "params.yaml").write_text("scenes:\n  mine: {source: simulate}\n")
    (root / "README.md").unlink()
    capsys.readouterr()
    assert main(["init", str(root)]) == 0
    shown = capsys.readouterr().out
    assert "README.md" in shown and "initialised" not in shown
    assert (root / "params.yaml").read_text() == "scenes:\n  mine: {source: simulate}\n"
    assert "mine" in (root / "dvc.yaml").read_text()
    assert main(["init", str(root)]) == 0
    assert "already a complete zipon project" in " ".join(capsys.readouterr().out.split())


def test_init_refuses_a_folder_that_is_not_a_zipon_project_and_names_what_is_there(tmp_path, capsys):
    root = tmp_path / "thesis"
    (root / "chapters").mkdir(parents=True)
    (root / "notes.txt").write_text("mine")
    (root / "params.yaml").write_text("lr: 0.1\n")  # someone else's params file
    assert main(["init", str(root)]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert f"{root}: not empty and not a zipon project (it holds chapters/, notes.txt, params.yaml)" in err
    assert sorted(p.name for p in root.iterdir()) == ["chapters", "notes.txt", "params.yaml"]
    (root / "file").write_text("")
    assert main(["init", str(root / "file")]) == 1
    assert "is a file, not a folder" in capsys.readouterr().err


def test_init_takes_an_empty_git_repository(tmp_path):
    """A fresh clone of an empty remote holds only .git: it becomes the project, its git kept."""
    root = tmp_path / "clone"
    subprocess.run(["git", "init", "-q", str(root)], check=True)
    head = (root / ".git" / "HEAD").read_text()
    assert main(["init", str(root)]) == 0
    assert (root / ".dvc").is_dir() and (root / ".git" / "HEAD").read_text() == head
