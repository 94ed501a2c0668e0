"""``zipon diff REV_A REV_B``: what changed between two versions of a dataset project, read from git alone.

A version is a git commit of the project: its params file, its manifests (``manifests/<scene>/<stage>.json``) and its
dataset card (``dataset.json``, :mod:`pipeline.project.card`). Nothing is built and no artifact is read: the params
keys come from the two params files (resolved, so a default made explicit is no change), the stages rebuilt and the
artifacts whose digests differ from the manifests, the goals added, removed or edited (by id, with their names) from
the cards.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.errors import ArtifactError, ConfigError, ZiponError
from pipeline.engine.manifest import Manifest
from pipeline.paths import CARD_JSON, Workspace
from pipeline.engine.stagegraph import params_changes


@dataclass
class Version:
    """What git holds of one revision of the project."""

    rev: str
    commit: str
    params: dict[str, Any]
    manifests: dict[tuple[str, str], Manifest]  # (scene, stage) -> manifest
    card: dict[str, Any] | None


@dataclass
class VersionDiff:
    a: Version
    b: Version
    params: list[str] = field(default_factory=list)  # "key old -> new"
    scenes_added: list[str] = field(default_factory=list)
    scenes_removed: list[str] = field(default_factory=list)
    rebuilt: list[dict[str, str]] = field(default_factory=list)  # scene, stage, why
    artifacts: list[dict[str, str | None]] = field(default_factory=list)  # scene, artifact, a, b
    goals: dict[str, dict[str, list[str]]] = field(default_factory=dict)  # scene -> added/removed/edited names
    notes: list[str] = field(default_factory=list)

    @property
    def empty(self) -> bool:
        return not (self.params or self.scenes_added or self.scenes_removed or self.rebuilt or self.artifacts
                    or any(any(v.values()) for v in self.goals.values()))

    def to_json(self) -> dict[str, Any]:
        return {"a": {"rev": self.a.rev, "commit": self.a.commit}, "b": {"rev": self.b.rev, "commit": self.b.commit},
                "params": self.params, "scenes_added": self.scenes_added, "scenes_removed": self.scenes_removed,
                "stages_rebuilt": self.rebuilt, "artifacts": self.artifacts, "goals": self.goals, "notes": self.notes}


class _Git:
    """Read-only access to the revisions of the git repository holding ``root``."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.git = shutil.which("git")
        if self.git is None:
            raise ZiponError("git not found on PATH: zipon diff reads the versions from git (install git)")
        self.prefix = self._run("rev-parse", "--show-prefix", what=f"{root} is not inside a git repository").strip()

    def _run(self, *args: str, what: str) -> str:
        done = subprocess.run([self.git, "-C", str(self.root), *args], capture_output=True, text=True)
        if done.returncode:
            said = (done.stderr or done.stdout).strip().splitlines()
            raise ConfigError(f"{what} (git: {said[-1] if said else 'failed'})")
        return done.stdout

    def commit(self, rev: str) -> str:
        done = subprocess.run([self.git, "-C", str(self.root), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
                              capture_output=True, text=True)
        if done.returncode:
            tags = subprocess.run([self.git, "-C", str(self.root), "tag", "--list"], capture_output=True,
                                  text=True).stdout.split()
            raise ConfigError(f"{rev}: not a revision of the git repository at {self.root} (tags: "
                              f"{', '.join(tags) or 'none'}; or a commit, a branch, HEAD~1)")
        return done.stdout.strip()

    def files(self, commit: str, folder: str) -> list[str]:
        out = self._run("ls-tree", "-r", "--name-only", commit, "--", self.prefix + folder,
                        what=f"cannot list {folder} at {commit}")
        return [line[len(self.prefix):] for line in out.splitlines()]

    def show(self, commit: str, rel: str) -> str | None:
        done = subprocess.run([self.git, "-C", str(self.root), "show", f"{commit}:{self.prefix}{rel}"],
                              capture_output=True, text=True)
        return done.stdout if done.returncode == 0 else None


def read_version(git: _Git, ws: Workspace, rev: str) -> Version:
    """The params, manifests and card ``rev`` holds (a params file it lacks is an error naming both)."""
    from pipeline.paramsfile import parse_params
    from pipeline.project.card import read_card
    from pipeline.userfiles import parse_yaml

    commit = git.commit(rev)
    params_rel = ws.params_path.relative_to(ws.root).as_posix()
    text = git.show(commit, params_rel)
    if text is None:
        raise ConfigError(f"{rev}: has no {params_rel} in {ws.root} (not a version of this dataset project)")
    origin = f"{rev}:{params_rel}"
    params = parse_params(parse_yaml(text, origin=origin) or {}, origin=origin).model_dump(mode="json")
    manifests_rel = ws.manifests_dir.relative_to(ws.root).as_posix()
    manifests = {}
    for rel in git.files(commit, manifests_rel + "/"):
        parts = Path(rel).relative_to(manifests_rel).parts
        if len(parts) != 2 or not parts[1].endswith(".json"):
            continue
        try:
            manifests[(parts[0], parts[1][:-5])] = Manifest.model_validate_json(git.show(commit, rel) or "")
        except ValueError as err:
            raise ArtifactError(f"{rev}:{rel}: not a valid zipon manifest ({str(err).splitlines()[0]})") from None
    card_text = git.show(commit, CARD_JSON)
    card = read_card(card_text, f"{rev}:{CARD_JSON}") if card_text is not None else None
    return Version(rev, commit, params, manifests, card)


def diff_versions(ws: Workspace, rev_a: str, rev_b: str) -> VersionDiff:
    """Compare two git revisions of the dataset project at ``ws.root``; see the module doc."""
    if ws.root != ws.params_path.parent or not ws.manifests_dir.is_relative_to(ws.root):
        raise ConfigError("zipon diff reads the manifests beside the params file from git; --manifests-dir "
                          f"{ws.manifests_dir} is outside {ws.root}")
    git = _Git(ws.root)
    a, b = read_version(git, ws, rev_a), read_version(git, ws, rev_b)
    d = VersionDiff(a, b)
    d.params = params_changes(a.params, b.params)
    d.scenes_added = sorted(set(b.params["scenes"]) - set(a.params["scenes"]))
    d.scenes_removed = sorted(set(a.params["scenes"]) - set(b.params["scenes"]))
    for key in sorted(set(a.manifests) | set(b.manifests)):
        ma, mb = a.manifests.get(key), b.manifests.get(key)
        scene, stage = key
        if ma is not None and mb is not None and ma.text() == mb.text():
            continue
        d.rebuilt.append({"scene": scene, "stage": stage, "why": _why(ma, mb)})
        outs_a = {n: r.digest for n, r in (ma.outputs.items() if ma else ())}
        outs_b = {n: r.digest for n, r in (mb.outputs.items() if mb else ())}
        d.artifacts += [{"scene": scene, "artifact": n, "a": outs_a.get(n), "b": outs_b.get(n)}
                        for n in sorted(set(outs_a) | set(outs_b)) if outs_a.get(n) != outs_b.get(n)]
    _goal_changes(d)
    return d


def _why(ma: Manifest | None, mb: Manifest | None) -> str:
    if ma is None:
        return "built only in B"
    if mb is None:
        return "built only in A"
    reasons = []
    if ma.code_digest != mb.code_digest:
        reasons.append(f"code changed (zipon {ma.code_version} -> {mb.code_version})"
                       if ma.code_version != mb.code_version else "code changed")
    if ma.params_digest != mb.params_digest:
        reasons.append("params: " + "; ".join(params_changes(ma.params, mb.params)))
    changed = sorted(k for k in set(ma.inputs) | set(mb.inputs) if ma.inputs.get(k) != mb.inputs.get(k))
    if changed:
        reasons.append(f"inputs changed: {', '.join(changed)}")
    if not reasons:
        same = {n: r.digest for n, r in ma.outputs.items()} == {n: r.digest for n, r in mb.outputs.items()}
        reasons.append("rebuilt from the same inputs" + (", same content" if same else ", content differs"))
    return " | ".join(reasons)


def _goal_changes(d: VersionDiff) -> None:
    """Goals added, removed and edited per scene, from the two cards (by goal id; names shown)."""
    cards = {"A": d.a.card, "B": d.b.card}
    for side, card in cards.items():
        if card is None:
            rev = d.a.rev if side == "A" else d.b.rev
            d.notes.append(f"{rev} has no {CARD_JSON} (written by `zipon run` / `zipon card`): goals not compared")
    if None in cards.values():
        return
    scenes_a, scenes_b = d.a.card["scenes"], d.b.card["scenes"]
    for scene in sorted(set(scenes_a) | set(scenes_b)):
        goals_a = {g["id"]: g for g in (scenes_a.get(scene) or {}).get("goal_list", [])}
        goals_b = {g["id"]: g for g in (scenes_b.get(scene) or {}).get("goal_list", [])}
        change = {
            "added": [f"{i} {goals_b[i]['name']!r}" for i in goals_b if i not in goals_a],
            "removed": [f"{i} {goals_a[i]['name']!r}" for i in goals_a if i not in goals_b],
            "edited": [_edited(goals_a[i], goals_b[i]) for i in goals_a
                       if i in goals_b and goals_a[i]["digest"] != goals_b[i]["digest"]],
        }
        if any(change.values()):
            d.goals[scene] = change


def _edited(a: dict[str, Any], b: dict[str, Any]) -> str:
    """``g1 'old name' -> 'new name' (type, room)``: what of one goal changed (the feedback when nothing listed)."""
    renamed = f" -> {b['name']!r}" if a["name"] != b["name"] else ""
    fields = [k for k in ("name", "type", "room", "objects") if a.get(k) != b.get(k)]
    return f"{a['id']} {a['name']!r}{renamed} ({', '.join(fields) or 'feedback'})"


def diff_text(d: VersionDiff) -> list[str]:
    """The diff as lines for people."""
    lines = [f"A = {d.a.rev} ({d.a.commit[:10]}), B = {d.b.rev} ({d.b.commit[:10]})"]
    if d.empty:
        return lines + ["no difference in params, manifests or goals"] + d.notes
    if d.scenes_added or d.scenes_removed:
        lines.append(f"scenes: added {d.scenes_added or 'none'}, removed {d.scenes_removed or 'none'}")
    lines += ["params:"] + [f"  {c}" for c in d.params] if d.params else ["params: unchanged"]
    lines += ["stages rebuilt:"] + [f"  {r['scene']}/{r['stage']}: {r['why']}" for r in d.rebuilt] \
        if d.rebuilt else ["stages rebuilt: none"]
    lines += ["artifacts whose digests differ:"] + [
        f"  {x['scene']}/{x['artifact']}: {x['a'] or '(none)'} -> {x['b'] or '(none)'}" for x in d.artifacts] \
        if d.artifacts else ["artifacts whose digests differ: none"]
    for scene, change in d.goals.items():
        for kind, names in change.items():
            lines += [f"goals {kind} in {scene}: {', '.join(names)}"] if names else []
    return lines + d.notes


def json_text(d: VersionDiff) -> str:
    return json.dumps(d.to_json(), indent=2) + "\n"
