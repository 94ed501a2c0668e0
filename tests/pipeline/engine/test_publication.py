"""A stage's output set and manifest are published together or not at all, whatever instant a kill hits.

Publication runs in a forked child that SIGKILLs itself before (or halfway through) its k-th change on
disk, for every k; the parent then recovers (itself killed at every instant of recovery, once) and
checks that the complete old set or the complete new set is in place, with a manifest that matches
its content and no leftovers.
"""

import functools
import os
import shutil
import signal
import tempfile
from pathlib import Path

import numpy as np
import pytest

from pipeline.engine import publication
from pipeline.errors import StageError
from pipeline.engine.manifest import Manifest, OutputRecord
from pipeline.engine.publication import check_inputs_unchanged, publish_outputs, read_journal, recover
from pipeline.engine.runner import run_stage
from pipeline.store import artifact_attrs, compressor, content_digest, new_group
from pipeline.engine.verify import verify_all
from tests.fixtures.toy_stages import TOY_STAGES

NAMES = ("a.zarr", "b_mesh.ply", "c_points.ply")

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="kills a forked child")


@pytest.fixture(autouse=True)
def _no_fsync(monkeypatch):
    """fsync matters for power loss only; a killed process loses nothing the kernel accepted. Skipping
    it keeps these hundreds of publications fast (~16 ms per fsync on the CI disk)."""
    monkeypatch.setattr(os, "fsync", lambda fd: None)


@functools.cache
def _template(version: int) -> tuple[Path, Manifest]:
    """One output set (a zarr store, two files; their content says which version) and its manifest."""
    folder = Path(tempfile.mkdtemp(prefix=f"zipon-publication-v{version}-"))
    g = new_group(folder / NAMES[0], artifact_attrs("recon", 1, "reconstruct", f"v{version}"))
    a = g.create_array("grid", shape=(8, 8), chunks=(4, 4), dtype="uint8", compressors=compressor())
    a[:] = np.full((8, 8), version, np.uint8)
    for name in NAMES[1:]:
        (folder / name).write_bytes(f"{name} version {version}\n".encode() * (version + 1))
    manifest = Manifest(stage="reconstruct", scene="s", code_version="t", code_digest="c", params={"v": version},
                        params_digest=f"p{version}", inputs={},
                        outputs={n: OutputRecord(path=n, digest=content_digest(folder / n)) for n in NAMES})
    return folder, manifest


def _build(folder: Path, version: int) -> dict[str, Path]:
    shutil.copytree(_template(version)[0], folder)
    return {name: folder / name for name in NAMES}


class Scene:
    """A data root with a published version and a finished new version waiting in a temporary folder."""

    def __init__(self, root: Path, *, old: bool = True):
        self.root = root
        self.final = {n: root / "artifacts" / n for n in NAMES}
        self.manifest_path = root / "manifests" / "reconstruct.json"
        self.journal = root / "artifacts" / ".reconstruct.publish.json"
        self.versions = {v: _template(v)[1] for v in (1, 2)}
        if old:
            built = _build(root / "tmp-old", 1)
            publish_outputs(self.journal, {self.final[n]: p for n, p in built.items()}, self.manifest_path,
                            self.versions[1])
        self.tmp = _build(root / "tmp-new", 2)

    def publish(self) -> None:
        publish_outputs(self.journal, {self.final[n]: p for n, p in self.tmp.items()}, self.manifest_path,
                        self.versions[2])

    def recover(self) -> str:
        return recover(self.journal, list(self.final.values()), self.manifest_path)

    def state(self) -> int:
        """Which complete version is published (0: none), after checking nothing is mixed or left over."""
        leftovers = [p.name for p in (self.root / "artifacts").iterdir() if p.name.startswith(".")]
        if self.manifest_path.parent.is_dir():
            leftovers += [p.name for p in self.manifest_path.parent.iterdir() if p.name.startswith(".")]
        assert leftovers == [], leftovers
        if not self.manifest_path.exists():
            assert not any(p.exists() for p in self.final.values()), "outputs without a manifest"
            return 0
        man = Manifest.read(self.manifest_path)
        version = man.params["v"]
        assert man.model_dump() == self.versions[version].model_dump()
        for name, path in self.final.items():  # byte-equal to the version's template (its digest is in man)
            assert _same_tree(path, _template(version)[0] / name), f"{name} is not version {version}'s"
        return version


def _same_tree(a: Path, b: Path) -> bool:
    if b.is_file():
        return a.is_file() and a.read_bytes() == b.read_bytes()
    files = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    return sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file()) == files and all(
        (a / f).read_bytes() == (b / f).read_bytes() for f in files)


def _changes_in(action) -> list[str]:
    """The changes on disk ``action`` makes, in order (run in a child, so nothing here changes)."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        seen = []
        for fn in ("_replace", "_write", "_remove"):
            orig = getattr(publication, fn)

            def counted(*args, _orig=orig, _fn=fn):
                seen.append(_fn)
                return _orig(*args)

            setattr(publication, fn, counted)
        try:
            action()
        except BaseException:  # noqa: BLE001 - never let the child return into pytest
            os._exit(1)
        os.write(write, " ".join(seen).encode())
        os._exit(0)
    os.close(write)
    os.waitpid(pid, 0)
    seen = os.read(read, 4096).decode().split()
    os.close(read)
    return seen


def _killed_at(action, k: int, halfway: bool) -> bool:
    """Run ``action`` in a child that SIGKILLs itself before its k-th change on disk (or halfway through
    it: a temporary file written but not renamed, a folder partly deleted). True if it was killed."""
    pid = os.fork()
    if pid == 0:
        count = [0]

        def die_half(fn, args):
            if fn == "_write":  # killed inside write_text_atomic: its temporary file is left behind
                path = Path(args[0])
                path.with_name(f".{path.name}.tmp-killed").write_text(args[1][: len(args[1]) // 2])
            elif fn == "_remove" and Path(args[0]).is_dir():  # killed inside rmtree
                next(p for p in Path(args[0]).rglob("*") if p.is_file()).unlink()
            elif fn == "_replace":
                pass  # a rename is atomic: halfway is before or after
            os.kill(os.getpid(), signal.SIGKILL)

        for fn in ("_replace", "_write", "_remove"):
            orig = getattr(publication, fn)

            def hooked(*args, _orig=orig, _fn=fn):
                if count[0] == k:
                    if halfway:
                        die_half(_fn, args)
                    os.kill(os.getpid(), signal.SIGKILL)
                count[0] += 1
                return _orig(*args)

            setattr(publication, fn, hooked)
        try:
            action()
        except BaseException:  # noqa: BLE001 - never let the child return into pytest
            os._exit(1)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL


@pytest.mark.parametrize("old", [True, False], ids=["replacing", "first"])
def test_a_kill_at_any_instant_of_publication_leaves_one_whole_version(tmp_path, old):
    changes = _changes_in(Scene(tmp_path / "count", old=old).publish)
    # journal, 2 renames per output (1 for a first version), manifest, commit, 3 asides and the journal removed
    assert changes == ["_write"] + ["_replace"] * (6 if old else 3) + ["_write"] * 2 + ["_remove"] * 4
    outcomes = set()
    for k, change in enumerate(changes):
        for halfway in (False, True) if change != "_replace" else (False,):  # a rename has no halfway
            scene = Scene(tmp_path / f"k{k}-{halfway}", old=old)
            assert _killed_at(scene.publish, k, halfway)
            pending = read_journal(scene.journal)
            done = scene.recover()
            version = scene.state()
            outcomes.add(version)
            # all temporary outputs are intact here, so an intent once recorded is always completed
            assert version == (2 if pending else (1 if old else 0)), (k, halfway, done)
            assert done == ("" if pending is None else "cleaned up" if pending.committed else "rolled forward")
            assert scene.recover() == "" and scene.state() == version  # recovery is idempotent
    assert outcomes == {1 if old else 0, 2}


def test_a_lost_temporary_output_rolls_back_to_the_old_set(tmp_path):
    rolled_back = 0
    for k in range(1, len(_changes_in(Scene(tmp_path / "count").publish))):
        scene = Scene(tmp_path / f"k{k}")
        assert _killed_at(scene.publish, k, False)
        journal = read_journal(scene.journal)
        unpublished = [Path(m.tmp) for m in journal.moves if Path(m.tmp).exists()]
        if not unpublished:
            continue
        # the dead run's temporary folder vanished (swept by an older zipon, or deleted by hand)
        for path in unpublished:
            publication.remove(path)
        assert scene.recover() == "rolled back"
        assert scene.state() == 1
        rolled_back += 1
    assert rolled_back == 6  # every instant before the last output was renamed in


@pytest.mark.parametrize("k, lose_tmp, want", [(4, False, 2), (4, True, 1), (10, False, 2)],
                         ids=["roll-forward", "roll-back", "cleanup"])
def test_a_kill_during_recovery_is_repaired_by_the_next_recovery(tmp_path, k, lose_tmp, want):
    def killed_scene(name):
        scene = Scene(tmp_path / name)
        assert _killed_at(scene.publish, k, False)  # k=4: amid the moves; k=10: after the commit
        if lose_tmp:
            publication.remove(scene.tmp["c_points.ply"])
        return scene

    steps = _changes_in(killed_scene("probe").recover)
    assert len(steps) >= 4
    for j in range(len(steps)):
        scene = killed_scene(f"j{j}")
        assert _killed_at(scene.recover, j, False)
        scene.recover()
        assert scene.state() == want


def test_an_error_inside_publication_restores_the_old_set(tmp_path, monkeypatch):
    scene = Scene(tmp_path / "s")
    calls = []
    real = publication._write

    def full_disk_on_manifest(path, text):
        calls.append(path)
        if Path(path) == scene.manifest_path:
            raise OSError(28, "No space left on device", str(path))
        real(path, text)

    monkeypatch.setattr(publication, "_write", full_disk_on_manifest)
    with pytest.raises(OSError, match="No space left"):
        scene.publish()
    assert scene.state() == 1
    assert not any(p.exists() for p in scene.tmp.values())  # the new outputs went with the journal


def test_publication_refuses_a_pending_journal(tmp_path):
    scene = Scene(tmp_path / "s")
    assert _killed_at(scene.publish, 3, False)
    with pytest.raises(StageError, match="unfinished publication is pending"):
        Scene.publish(scene)


def test_recovery_removes_stray_asides_without_a_journal(tmp_path):
    scene = Scene(tmp_path / "s")
    stray = scene.final["a.zarr"].with_name(".a.zarr.old-1234abcd")  # left by a kill inside store.publish
    stray.mkdir()
    (stray / "zarr.json").write_text("{}")
    assert scene.recover() == ""
    assert not stray.exists() and scene.state() == 1


def test_run_stage_recovers_a_publication_killed_by_sigkill(workspace, tmp_path):
    """End to end: a real `run_stage` process is SIGKILLed between renaming the old frames aside and
    renaming the new ones in; the next run_stage finishes the publication and verify agrees."""
    import subprocess
    import sys

    from pipeline.paramsfile import load_params

    params = load_params(workspace.params_path, ["simulate.frames=8"])
    for stage in ("simulate", "ingest"):
        run_stage(workspace, params, TOY_STAGES, "s0", stage, show_progress=False)
    frames = workspace.artifact("frames", "s0")
    code = (
        "import os, signal; from pipeline.engine import publication; from pipeline.paramsfile import load_params;"
        "from pipeline.paths import Workspace; from pipeline.engine.runner import run_stage;"
        "from tests.fixtures.toy_stages import TOY_STAGES;"
        "real = publication._replace; n = [0]\n"
        "def hooked(a, b):\n"
        "    n[0] += 1\n"
        "    real(a, b)\n"
        "    if n[0] == 1: os.kill(os.getpid(), signal.SIGKILL)\n"
        "publication._replace = hooked\n"
        f"ws = Workspace.resolve({str(workspace.params_path)!r})\n"
        "run_stage(ws, load_params(ws.params_path, ['simulate.frames=8', 'ingest.block_frames=4']), TOY_STAGES,"
        " 's0', 'ingest', show_progress=False)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=str(Path(__file__).parents[3]), timeout=120)
    assert proc.returncode == -signal.SIGKILL
    assert not frames.exists() and workspace.journal("s0", "ingest").exists()  # killed amid the set
    new = load_params(workspace.params_path, ["simulate.frames=8", "ingest.block_frames=4"])
    outcome = run_stage(workspace, new, TOY_STAGES, "s0", "ingest", show_progress=False)
    assert outcome.status == "skipped"  # rolled forward: the killed run's outputs are published and current
    assert all(r.ok for r in verify_all(workspace, new, TOY_STAGES))
    assert not workspace.journal("s0", "ingest").exists()
    assert [p.name for p in frames.parent.iterdir() if p.name.startswith(".") and p.name != ".tmp"] == []
    assert list(workspace.tmp_dir("s0").iterdir()) == []  # the dead run's temporary folder was swept


def test_inputs_republished_during_a_stage_are_refused(workspace):
    from pipeline.paramsfile import load_params

    params = load_params(workspace.params_path, ["simulate.frames=8"])
    run_stage(workspace, params, TOY_STAGES, "s0", "simulate", show_progress=False)
    digest = Manifest.read(workspace.manifest("s0", "simulate")).outputs["raw_log"].digest
    check_inputs_unchanged(workspace, "s0", "ingest", ["simulate"], {"raw_log": digest})
    with pytest.raises(StageError, match=r"input\(s\) \['raw_log'\] changed while stage ingest ran"):
        check_inputs_unchanged(workspace, "s0", "ingest", ["simulate"], {"raw_log": "blake2b:old"})
    workspace.journal("s0", "simulate").write_text("{}")
    with pytest.raises(StageError, match="input stage simulate has a publication in flight"):
        check_inputs_unchanged(workspace, "s0", "ingest", ["simulate"])
