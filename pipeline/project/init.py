"""``zipon init DIR``: a dataset project anywhere.

It writes a commented ``params.yaml`` (one simulated scene to start from, the recorded formats as examples, every
tunable with its description), a ``.gitignore``, a short ``README.md`` (build, version, push, restore), initialises git
and DVC offline (DVC's analytics and update checks off in ``.dvc/config``) and writes ``dvc.yaml`` with the stages'
code identity files (:mod:`pipeline.engine.dvcfile`). A folder that already is a zipon project is completed (what it lacks is
written, nothing it has is changed); any other non-empty folder is refused, naming what is in it.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.config import Params
from pipeline.errors import ConfigError, ZiponError
from pipeline.paths import CODE_ID, PARAMS_FILE, Workspace
from pipeline.engine.stagegraph import StageSpec

#: entries a folder may hold and still be initialised: an empty git repository (a fresh clone of an empty remote)
ALLOWED_IN_EMPTY = {".git"}

SCENE_EXAMPLES = """\
  # One entry per scene: NAME: {source: PATH | simulate, format: auto | mcap | rosbag | tum | 7scenes | replica |
  # scannet | navchat}. A recorded source is a path relative to this file; track it with DVC so it is versioned
  # and pushed with the rest (`dvc add raw/desk`), e.g.
  #   desk: {source: raw/rgbd_dataset_freiburg1_desk, format: tum}
  #   chess: {source: raw/7scenes/chess/seq-01, format: 7scenes}
  #   office: {source: raw/office.mcap}
"""

GITIGNORE = """\
# zipon dataset project. Built artifacts are tracked by DVC (dvc.lock) and pushed to a DVC remote, never to git;
# git holds params.yaml, dvc.yaml, dvc.lock, manifests/, .zipon/ (the stages' code identities) and the card.
/data/
# local mirror of an object-store data root (zipon run --data-dir s3://...)
/.zipon-cache/
# evaluation outputs (zipon eval --out)
/eval_out/
"""

README = """\
# {name}: a zipon dataset

Built by zipon from `params.yaml`; every version is a git commit (params, `dvc.lock`, the
manifests under `manifests/`, the dataset card `DATASET.md` / `dataset.json`) plus its artifacts in a DVC remote.

## Build

```bash
zipon run                 # builds every stage of every scene; records dvc.lock and refreshes DATASET.md
zipon verify              # re-hashes every artifact against its manifest
zipon status --check      # exit 0: the dataset is current
```

## Version

```bash
git add -A && git commit -m "v1" && git tag v1
# change params.yaml (e.g. goals.max_goals), then
zipon run && git add -A && git commit -m "v2" && git tag v2
zipon diff v1 v2          # params keys, stages rebuilt, artifacts and goals that differ
```

## Share

```bash
dvc remote add -d storage /mnt/datasets/{name}     # or s3://bucket/{name}; commit it: clones then know it
zipon push --all-tags && git push origin HEAD --tags
```

## Restore

```bash
git clone REPO {name} && cd {name}
git checkout v1 && zipon pull && zipon verify && zipon status --check
```

`zipon dvc --check` names a `dvc.yaml` edited by hand (it is generated: `zipon dvc`). After upgrading zipon, run
`zipon dvc`: the code identity files `.zipon/code/STAGE.json` change for exactly the stages whose code changed,
and `zipon status` / `dvc status` name them.
"""


@dataclass
class InitResult:
    root: Path
    written: list[Path] = field(default_factory=list)
    initialised: list[str] = field(default_factory=list)  # "git", "dvc"


def is_zipon_project(root: Path) -> bool:
    """Whether ``root`` holds a zipon project: a params file beside a zipon-generated ``dvc.yaml`` or code identity
    files."""
    from pipeline.engine.dvcfile import HEADER

    if not (root / PARAMS_FILE).is_file():
        return False
    dvc_yaml = root / "dvc.yaml"
    generated = dvc_yaml.is_file() and dvc_yaml.read_text(errors="replace").startswith(HEADER)
    return generated or (root / CODE_ID.split("{")[0]).is_dir()


def starting_params() -> tuple[str, Params]:
    """The text and values of a new project's ``params.yaml``: one simulated scene, examples of recorded ones."""
    from pipeline.paramsfile import params_yaml, parse_params

    params = parse_params({"scenes": {"sim_00": {"source": "simulate"}}})
    text = params_yaml(params).replace("\nscenes:\n", "\nscenes:\n" + SCENE_EXAMPLES, 1)
    return text, params


def _refuse_foreign(root: Path) -> None:
    if not root.exists():
        return
    if not root.is_dir():
        raise ConfigError(f"{root}: is a file, not a folder; zipon init needs a new or empty folder")
    entries = sorted(p.name + ("/" if p.is_dir() else "") for p in root.iterdir() if p.name not in ALLOWED_IN_EMPTY)
    if entries and not is_zipon_project(root):
        shown = ", ".join(entries[:8]) + (f" and {len(entries) - 8} more" if len(entries) > 8 else "")
        raise ConfigError(f"{root}: not empty and not a zipon project (it holds {shown}); zipon init makes a new "
                          "project in a new or empty folder")


def init_project(root: Path, stages: dict[str, StageSpec]) -> InitResult:
    """Create (or complete) a dataset project at ``root``; see the module doc. Raises :class:`ConfigError` for a
    foreign folder and :class:`ZiponError` when git or DVC cannot initialise it."""
    from pipeline.engine.dvcfile import write_dvc_files
    from pipeline.paramsfile import load_params
    from pipeline.store import write_text_atomic

    root = Path(root).expanduser().resolve()
    _refuse_foreign(root)
    root.mkdir(parents=True, exist_ok=True)
    result = InitResult(root)
    params_text, _ = starting_params()
    for name, text in ((PARAMS_FILE, params_text), (".gitignore", GITIGNORE), ("README.md", README)):
        path = root / name
        if not path.exists():
            write_text_atomic(path, text.replace("{name}", root.name) if name == "README.md" else text)
            result.written.append(path)
    if not (root / ".git").exists():
        _git_init(root)
        result.initialised.append("git")
    if not (root / ".dvc").is_dir():
        _dvc_init(root)
        result.initialised.append("dvc")
    ws = Workspace.resolve(root / PARAMS_FILE, root / "data", root / "manifests")
    result.written += write_dvc_files(ws, load_params(ws.params_path), stages)
    return result


def _git_init(root: Path) -> None:
    git = shutil.which("git")
    if git is None:
        raise ZiponError("git not found on PATH: a zipon dataset project is a git repository (install git)")
    done = subprocess.run([git, "init", "-q", str(root)], capture_output=True, text=True)
    if done.returncode:
        raise ZiponError(f"{root}: git init failed: {(done.stderr or done.stdout).strip()}")


def _dvc_init(root: Path) -> None:
    """``dvc init`` through DVC's API (nothing leaves the machine), then analytics and update checks off."""
    from dvc.repo import Repo

    from pipeline import logs

    logs.tame_driven()  # importing dvc set its logger to info: its "Initialized DVC repository." and hints
    try:
        repo = Repo.init(str(root))
        with repo.config.edit("repo") as conf:
            conf.setdefault("core", {}).update({"analytics": False, "check_update": False})
        repo.close()
    except Exception as err:  # noqa: BLE001 - DVC's own errors have no common base worth naming
        raise ZiponError(f"{root}: dvc init failed ({type(err).__name__}: {err})") from None
